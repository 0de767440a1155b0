//! Bearer tokens with scopes. The tokens file holds only each token's BLAKE3 hash, with a name and
//! scopes; it is read again when it changes (looked at once a second) or on SIGHUP, without a
//! restart. A token is never logged: only its name is.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::RwLock;
use std::time::{Duration, Instant, SystemTime};

/// What a token may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Scope {
    /// GET and HEAD occluders, reports and job state.
    Read,
    /// POST /v1/cook and /v1/levels.
    Cook,
    /// Metrics and maintenance.
    Admin,
}

impl Scope {
    pub fn name(self) -> &'static str {
        match self {
            Scope::Read => "read",
            Scope::Cook => "cook",
            Scope::Admin => "admin",
        }
    }
}

/// One token of the file: `[[token]]` with `name`, `scopes` and `blake3` (the hex hash).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    pub name: String,
    pub scopes: Vec<Scope>,
    pub blake3: String,
}

#[derive(Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    token: Vec<Entry>,
}

/// The tokens a server accepts, from its file, and what each may still submit.
pub struct Tokens {
    path: PathBuf,
    loaded: RwLock<Loaded>,
    submissions: Buckets,
}

/// Submissions per token name: a bucket of `burst` that refills at `rate` a second.
struct Buckets {
    rate: f64,
    burst: f64,
    held: std::sync::Mutex<std::collections::HashMap<String, (f64, Instant)>>,
}

struct Loaded {
    tokens: Vec<(blake3::Hash, Entry)>,
    modified: Option<SystemTime>,
    looked: Instant,
}

/// How often a request looks whether the file changed.
const LOOK_EVERY: Duration = Duration::from_secs(1);

impl Tokens {
    /// Reads the file; a missing or malformed one is an error naming it. Each token may submit
    /// `burst` jobs at once and `rate` a second after that.
    pub fn open(path: &Path, rate: f64, burst: f64) -> Result<Tokens, String> {
        let loaded = read(path)?;
        Ok(Tokens {
            path: path.to_path_buf(),
            loaded: RwLock::new(loaded),
            submissions: Buckets {
                rate,
                burst,
                held: Default::default(),
            },
        })
    }

    /// Takes one submission from `name`'s bucket; when it is empty, the seconds until one is
    /// there again.
    pub fn take_submission(&self, name: &str) -> Result<(), f64> {
        let Buckets { rate, burst, held } = &self.submissions;
        let mut held = held.lock().unwrap_or_else(|e| e.into_inner());
        let (left, since) = held.entry(name.to_string()).or_insert((*burst, Instant::now()));
        *left = (*left + since.elapsed().as_secs_f64() * rate).min(*burst);
        *since = Instant::now();
        match *left >= 1.0 {
            true => {
                *left -= 1.0;
                Ok(())
            }
            false => Err((1.0 - *left) / rate),
        }
    }

    /// Reads the file again (SIGHUP). A file that no longer reads keeps the tokens as they were.
    pub fn reload(&self) {
        match read(&self.path) {
            Ok(loaded) => {
                tracing::info!("read {} tokens from {}", loaded.tokens.len(), self.path.display());
                *self.loaded.write().unwrap_or_else(|e| e.into_inner()) = loaded;
            }
            Err(e) => tracing::warn!("{e}; the tokens stay as they were"),
        }
    }

    /// The entry of `token`, if the file holds its hash. Hashes compare in constant time.
    pub fn check(&self, token: &str) -> Option<Entry> {
        self.reload_if_changed();
        let hash = blake3::hash(token.as_bytes());
        let loaded = self.loaded.read().unwrap_or_else(|e| e.into_inner());
        // Every entry is compared, so the time taken says nothing of which one matched.
        let mut found = None;
        for (known, entry) in &loaded.tokens {
            if *known == hash {
                found = Some(entry.clone());
            }
        }
        found
    }

    fn reload_if_changed(&self) {
        let due = self.loaded.read().unwrap_or_else(|e| e.into_inner()).looked.elapsed() >= LOOK_EVERY;
        if !due {
            return;
        }
        let modified = modified(&self.path);
        let changed = {
            let mut loaded = self.loaded.write().unwrap_or_else(|e| e.into_inner());
            loaded.looked = Instant::now();
            loaded.modified != modified
        };
        if changed {
            self.reload();
        }
    }
}

fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

fn read(path: &Path) -> Result<Loaded, String> {
    let modified = modified(path);
    let text =
        std::fs::read_to_string(path).map_err(|e| format!("cannot read the tokens file {}: {e}", path.display()))?;
    let file: File = toml::from_str(&text)
        .map_err(|e| format!("the tokens file {} is malformed: {}", path.display(), e.message()))?;
    let tokens = file
        .token
        .into_iter()
        .map(|entry| {
            let hash = blake3::Hash::from_hex(&entry.blake3).map_err(|_| {
                format!(
                    "token `{}` in {}: blake3 is not 64 hex digits",
                    entry.name,
                    path.display()
                )
            })?;
            Ok((hash, entry))
        })
        .collect::<Result<_, String>>()?;
    Ok(Loaded {
        tokens,
        modified,
        looked: Instant::now(),
    })
}

/// A new token (`oct_` and 64 hex digits from the system's random source) and its entry.
pub fn new_token(name: &str, scopes: &[Scope]) -> Result<(String, Entry), String> {
    let mut secret = [0u8; 32];
    getrandom::fill(&mut secret).map_err(|e| format!("no random source: {e}"))?;
    let token = format!("oct_{}", blake3::Hash::from_bytes(secret).to_hex());
    let entry = Entry {
        name: name.to_string(),
        scopes: scopes.to_vec(),
        blake3: blake3::hash(token.as_bytes()).to_hex().to_string(),
    };
    Ok((token, entry))
}

/// Appends `entry` to the tokens file at `path`, creating it (readable by its owner only).
pub fn append(path: &Path, entry: Entry) -> Result<(), String> {
    use std::io::Write;
    let text = toml::to_string(&File { token: vec![entry] }).expect("an entry serializes");
    let mut options = std::fs::OpenOptions::new();
    options.create(true).append(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut file = options
        .open(path)
        .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    write!(file, "\n{text}").map_err(|e| format!("cannot write {}: {e}", path.display()))
}
