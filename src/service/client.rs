//! The CLI clients CI runs against a server: `submit` and `fetch`, with exit codes a build can
//! trust (see [`Exit`]).

use crate::config::Settings;
use crate::key::cache_key;
use crate::mesh::{Format, load_file};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Why a client run failed, as its exit code.
#[derive(Debug, thiserror::Error)]
pub enum Exit {
    /// 2: the server refused the request (4xx): a bad mesh, bad settings, unknown key.
    #[error("{0}")]
    Rejected(String),
    /// 3: a job ran and failed.
    #[error("{0}")]
    JobFailed(String),
    /// 4: the server could not be reached or failed (5xx, 429 after retries).
    #[error("{0}")]
    Unavailable(String),
    /// 1: a local problem (unreadable file, cannot write the output).
    #[error("{0}")]
    Local(String),
}

impl Exit {
    pub fn code(&self) -> i32 {
        match self {
            Exit::Local(_) => 1,
            Exit::Rejected(_) => 2,
            Exit::JobFailed(_) => 3,
            Exit::Unavailable(_) => 4,
        }
    }
}

/// A server's answer: status and body.
struct Reply {
    status: u16,
    body: Vec<u8>,
}

impl Reply {
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }

    /// The error message of a JSON error body, or the status.
    fn error(&self) -> String {
        let j = self.json();
        match j["error"]["message"].as_str() {
            Some(m) => format!("{} ({})", m, j["error"]["code"].as_str().unwrap_or("error")),
            None => format!("HTTP {}", self.status),
        }
    }

    /// Turns a non-success status into the exit it means.
    fn check(self, what: &str) -> Result<Reply, Exit> {
        match self.status {
            200..=299 | 304 => Ok(self),
            429 | 500..=599 => Err(Exit::Unavailable(format!("{what}: {}", self.error()))),
            _ => Err(Exit::Rejected(format!("{what}: {}", self.error()))),
        }
    }
}

pub struct Client {
    agent: ureq::Agent,
    server: String,
    /// The `Authorization` header's value, when a token is given.
    authorization: Option<String>,
}

impl Client {
    /// A client of `server` (http:// or https://). `ca_cert`: a PEM file of the certificates an
    /// https server's must chain to, in place of the public roots (a self-signed server's).
    pub fn new(server: &str, token: Option<String>, ca_cert: Option<&Path>) -> Result<Client, Exit> {
        let tls = match ca_cert {
            Some(path) => {
                let pem = std::fs::read(path)
                    .map_err(|e| Exit::Local(format!("cannot read --ca-cert {}: {e}", path.display())))?;
                trusting(&pem).map_err(|e| Exit::Local(format!("--ca-cert {}: {e}", path.display())))?
            }
            None => ureq::tls::TlsConfig::default(),
        };
        let agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(600)))
            .tls_config(tls)
            .build()
            .into();
        Ok(Client {
            agent,
            server: server.trim_end_matches('/').to_string(),
            authorization: token.map(|t| format!("Bearer {t}")),
        })
    }

    /// `request` with the token, if any.
    fn authorized<B>(&self, request: ureq::RequestBuilder<B>) -> ureq::RequestBuilder<B> {
        match &self.authorization {
            Some(value) => request.header("Authorization", value),
            None => request,
        }
    }

    fn reply(&self, result: Result<ureq::http::Response<ureq::Body>, ureq::Error>, what: &str) -> Result<Reply, Exit> {
        let mut response =
            result.map_err(|e| Exit::Unavailable(format!("{what}: {} unreachable: {e}", self.server)))?;
        let status = response.status().as_u16();
        let body = response
            .body_mut()
            .with_config()
            .limit(u64::MAX)
            .read_to_vec()
            .map_err(|e| Exit::Unavailable(format!("{what}: {e}")))?;
        Ok(Reply { status, body })
    }

    fn get(&self, path: &str) -> Result<Reply, Exit> {
        let url = format!("{}{path}", self.server);
        self.reply(self.authorized(self.agent.get(&url)).call(), &url)
    }

    fn head(&self, path: &str) -> Result<u16, Exit> {
        let url = format!("{}{path}", self.server);
        Ok(self.reply(self.authorized(self.agent.head(&url)).call(), &url)?.status)
    }

    /// Writes the occluder of `key` to `out`.
    pub fn fetch(&self, key: &str, out: &Path) -> Result<(), Exit> {
        let reply = self.get(&format!("/v1/occluders/{key}"))?.check("fetch")?;
        std::fs::write(out, &reply.body).map_err(|e| Exit::Local(format!("cannot write {}: {e}", out.display())))
    }

    /// Uploads `file` (unless the server has its key already), waits for the job if `wait`,
    /// and writes `<stem>.occluder.glb` into `out_dir`. Returns the key.
    pub fn submit(
        &self,
        file: &Path,
        settings: &Settings,
        query: &[(String, String)],
        wait: bool,
        out_dir: &Path,
    ) -> Result<String, Exit> {
        let name = file.display().to_string();
        let (mesh, _) = load_file(file, &settings.ingest_limits()).map_err(|e| Exit::Local(format!("{name}: {e}")))?;
        let out = out_dir.join(format!(
            "{}.occluder.glb",
            file.file_stem().unwrap_or_default().to_string_lossy()
        ));
        // The key is known offline: a HEAD saves the upload when the result exists.
        let local_key = cache_key(&mesh, &settings.cook);
        if self.head(&format!("/v1/occluders/{local_key}"))? == 200 {
            if wait {
                self.fetch(&local_key, &out)?;
            }
            return Ok(local_key);
        }
        let format = Format::from_extension(file)
            .map_err(|e| Exit::Local(format!("{name}: {e}")))?
            .name();
        let bytes = std::fs::read(file).map_err(|e| Exit::Local(format!("{name}: {e}")))?;
        let mut url = format!("{}/v1/cook?format={format}", self.server);
        for (k, v) in query {
            url.push_str(&format!("&{}={}", urlencoding::encode(k), urlencoding::encode(v)));
        }
        let accepted = self
            .reply(
                self.authorized(self.agent.post(&url))
                    .content_type("application/octet-stream")
                    .send(&bytes[..]),
                &name,
            )?
            .check(&name)?
            .json();
        let key = accepted["key"].as_str().unwrap_or(&local_key).to_string();
        if wait {
            let job = accepted["job"].as_str().unwrap_or_default().to_string();
            self.wait(&job, &name)?;
            self.fetch(&key, &out)?;
        }
        Ok(key)
    }

    /// Uploads a level manifest with the meshes it names (files next to it; a name with no file
    /// must be the key of a mesh the server has), waits for the bake, and returns its key and
    /// report; the level's GLB is written to `out`.
    pub fn submit_level(
        &self,
        manifest: &Path,
        query: &[(String, String)],
        out: &Path,
    ) -> Result<(String, Value), Exit> {
        let name = manifest.display().to_string();
        let text = std::fs::read(manifest).map_err(|e| Exit::Local(format!("cannot read {name}: {e}")))?;
        let parsed = crate::level::parse_manifest(&name, &text).map_err(|e| Exit::Local(e.to_string()))?;
        let dir = manifest.parent().unwrap_or(Path::new("."));
        let mut meshes: Vec<&str> = parsed.instances.iter().map(|i| i.mesh.as_str()).collect();
        meshes.sort_unstable();
        meshes.dedup();
        let mut uploads = Vec::new();
        for mesh in meshes {
            let file = dir.join(mesh);
            if file.is_file() {
                let bytes =
                    std::fs::read(&file).map_err(|e| Exit::Local(format!("cannot read {}: {e}", file.display())))?;
                uploads.push((mesh, bytes));
            } else if !crate::level::is_key(&mesh.to_ascii_lowercase()) {
                return Err(Exit::Local(format!(
                    "{name}: mesh `{mesh}` is neither a file next to the manifest nor a key"
                )));
            }
        }
        let parts: Vec<(&str, &str, &[u8])> = std::iter::once(("manifest", "level.json", &text[..]))
            .chain(uploads.iter().map(|(mesh, bytes)| ("mesh", *mesh, &bytes[..])))
            .collect();
        let (content_type, body) = multipart(&parts);
        let mut url = format!("{}/v1/levels?", self.server);
        for (k, v) in query {
            url.push_str(&format!("{}={}&", urlencoding::encode(k), urlencoding::encode(v)));
        }
        let accepted = self
            .reply(
                self.authorized(self.agent.post(url.trim_end_matches(['?', '&'])))
                    .content_type(&content_type)
                    .send(&body[..]),
                &name,
            )?
            .check(&name)?
            .json();
        let key = accepted["key"].as_str().unwrap_or_default().to_string();
        if let Some(job) = accepted["job"].as_str() {
            self.wait(job, &name)?;
        }
        self.fetch(&key, out)?;
        let report = self.get(&format!("/v1/occluders/{key}/report"))?.check(&name)?.json();
        Ok((key, report))
    }

    /// Polls a job until it ends, with a progress bar on stderr.
    fn wait(&self, job: &str, name: &str) -> Result<(), Exit> {
        let bar = stage_bar(name);
        loop {
            let status = self.get(&format!("/v1/jobs/{job}"))?.check(name)?.json();
            bar.set_position((status["progress"].as_f64().unwrap_or(0.0) * 1000.0) as u64);
            bar.set_message(format!(
                "{} {}",
                status["state"].as_str().unwrap_or("?"),
                status["stage"].as_str().unwrap_or("")
            ));
            match status["state"].as_str() {
                Some("done") => {
                    bar.finish_with_message("done");
                    return Ok(());
                }
                Some("failed") => {
                    bar.abandon_with_message("failed");
                    return Err(Exit::JobFailed(format!(
                        "{name}: job {job} failed: {}",
                        status["error"]["message"].as_str().unwrap_or("unknown error")
                    )));
                }
                _ => std::thread::sleep(Duration::from_millis(200)),
            }
        }
    }
}

/// TLS that trusts the certificates in `pem` in place of the public roots.
pub fn trusting(pem: &[u8]) -> Result<ureq::tls::TlsConfig, String> {
    let certs = ureq::tls::parse_pem(pem)
        .filter_map(|item| match item {
            Ok(ureq::tls::PemItem::Certificate(cert)) => Some(Ok(cert)),
            Ok(_) => None,
            Err(e) => Some(Err(e.to_string())),
        })
        .collect::<Result<Vec<_>, _>>()?;
    if certs.is_empty() {
        return Err("no PEM certificate in it".into());
    }
    Ok(ureq::tls::TlsConfig::builder()
        .root_certs(ureq::tls::RootCerts::new_with_certs(&certs))
        .build())
}

/// A multipart/form-data body of (field, file name, bytes) parts, and its content type.
pub fn multipart(parts: &[(&str, &str, &[u8])]) -> (String, Vec<u8>) {
    let boundary = format!("occluder-cook-{:016x}", fastrand::u64(..));
    let mut body = Vec::new();
    for (field, file, bytes) in parts {
        let file = file.replace(['"', '\r', '\n'], "_");
        body.extend_from_slice(
            format!(
                "--{boundary}\r\nContent-Disposition: form-data; name=\"{field}\"; filename=\"{file}\"\r\n\
                 Content-Type: application/octet-stream\r\n\r\n"
            )
            .as_bytes(),
        );
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// A bar of a job's progress (0 to 1000) and stage, named `name`, on stderr; drawn only where
/// stderr is a terminal, so that CI logs stay quiet.
pub fn stage_bar(name: &str) -> ProgressBar {
    ProgressBar::new(1000)
        .with_style(bar_style("{prefix} [{bar:30}] {msg}"))
        .with_prefix(name.to_string())
}

/// A bar that counts `what` (its length set as the count is known), like [`stage_bar`].
pub fn count_bar(what: &str) -> ProgressBar {
    ProgressBar::new(0)
        .with_style(bar_style("{prefix} [{bar:30}] {pos}/{len} {msg}"))
        .with_prefix(what.to_string())
}

fn bar_style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template)
        .expect("the template parses")
        .progress_chars("=> ")
}

/// The output folder, created if needed.
pub fn output_dir(dir: Option<PathBuf>) -> Result<PathBuf, Exit> {
    let dir = dir.unwrap_or_else(|| ".".into());
    std::fs::create_dir_all(&dir).map_err(|e| Exit::Local(format!("cannot create {}: {e}", dir.display())))?;
    Ok(dir)
}
