//! HTTPS for `serve`: rustls with the certificate chain and key of `service.tls_cert` and
//! `service.tls_key`, read again whenever either file changes, so that a renewed certificate
//! (cert-manager, a rotated Kubernetes Secret) is served without a restart.

use anyhow::Context;
use axum_server::tls_rustls::RustlsConfig;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// How often the files are looked at.
const LOOK_EVERY: Duration = Duration::from_secs(1);

/// The certificate and key files, and the config made from them.
#[derive(Clone)]
pub struct Tls {
    pub config: RustlsConfig,
    cert: PathBuf,
    key: PathBuf,
}

impl Tls {
    /// Reads both PEM files; an unreadable or mismatched pair is an error naming them.
    pub async fn open(cert: &Path, key: &Path) -> anyhow::Result<Tls> {
        // Only ring is built in; rustls needs it named once per process.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let config = RustlsConfig::from_pem_file(cert, key).await.with_context(|| {
            format!(
                "cannot use service.tls_cert {} with service.tls_key {}",
                cert.display(),
                key.display()
            )
        })?;
        Ok(Tls {
            config,
            cert: cert.to_path_buf(),
            key: key.to_path_buf(),
        })
    }

    /// Reloads the pair whenever either file's modification time changes. A pair that fails
    /// to load (a half-written renewal) leaves the served one in place and is tried again.
    pub async fn reload_on_change(self) {
        let mut seen = self.modified();
        loop {
            tokio::time::sleep(LOOK_EVERY).await;
            let now = self.modified();
            if now == seen {
                continue;
            }
            match self.config.reload_from_pem_file(&self.cert, &self.key).await {
                Ok(()) => {
                    tracing::info!(cert = %self.cert.display(), "TLS certificate reloaded");
                    seen = now;
                }
                Err(e) => {
                    tracing::warn!(cert = %self.cert.display(), error = %e, "cannot reload the TLS certificate yet")
                }
            }
        }
    }

    fn modified(&self) -> [Option<SystemTime>; 2] {
        let modified = |path: &Path| std::fs::metadata(path).and_then(|m| m.modified()).ok();
        [modified(&self.cert), modified(&self.key)]
    }
}
