//! `soak`: the real server under mixed load for a set time, killed with SIGKILL and started
//! again on a schedule, to show that it loses no job, serves no wrong bytes and holds its memory.
//!
//! The server is this binary's `serve` on a loopback port, with tokens, over a scratch folder;
//! or, with worker nodes, a cluster on a NATS server: that `serve` as the API node, running no
//! cook itself, and this binary's `worker`s, killed in turn with it.
//! Client threads mix new meshes (whose keys are computed here too), duplicates, job polls,
//! cached GETs, malformed and oversized bodies, and calls without a valid token; each answer is
//! checked against what the API promises. After the load, every accepted job is waited for.

use crate::config::Settings;
use crate::mesh::{Format, load_bytes};
use crate::service::auth::{self, Scope};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::ffi::OsStr;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

pub struct SoakOptions {
    pub duration: Duration,
    /// Time between SIGKILLs of a node: the server, or with worker nodes, it and each of them
    /// in turn.
    pub restart_every: Duration,
    /// Client threads.
    pub clients: usize,
    /// Scratch folder: the server's data, tokens file and log.
    pub dir: PathBuf,
    /// The binary to run as the server.
    pub binary: PathBuf,
    /// `service.*` settings for the server and the worker nodes, as `KEY=VALUE`.
    pub server_settings: Vec<String>,
    /// `worker` processes on the NATS server that `service.nats_url` names (it must be set);
    /// the API node then runs no cook.
    pub worker_nodes: usize,
}

/// What a soak saw.
#[derive(Debug, Default, Serialize)]
pub struct SoakReport {
    pub seconds: f64,
    /// SIGKILLs of the API node (the server), and of worker nodes.
    pub restarts: usize,
    pub worker_restarts: usize,
    /// Requests sent, by kind.
    pub requests: BTreeMap<String, u64>,
    /// Answers the API does not allow for that request, by `kind status`.
    pub unexpected: BTreeMap<String, u64>,
    /// Requests with no answer or 503, by kind: the server was being killed or starting, or
    /// (oversized bodies) it answered 413 and closed before the body was all sent.
    pub unavailable: BTreeMap<String, u64>,
    /// Submissions refused with 429 (the token's rate or queue).
    pub busy: u64,
    pub jobs_accepted: usize,
    pub jobs_done: usize,
    /// Failed, besides those cancelled.
    pub jobs_failed: usize,
    /// Ended `failed` with code `cancelled`.
    pub jobs_cancelled: usize,
    /// Jobs a DELETE answered 200 that ended otherwise.
    pub cancels_undone: usize,
    /// Accepted jobs that never ended, or that the server no longer knows.
    pub jobs_lost: usize,
    /// Jobs seen ended that were started more than once: a kill stopped their first cook.
    pub jobs_started_again: usize,
    pub occluders_fetched: u64,
    /// Fetches whose bytes differed from the first fetch of the same key.
    pub wrong_bytes: u64,
    /// Submissions answered with another key than the mesh's own.
    pub wrong_keys: u64,
    pub minutes: Vec<Minute>,
    /// How far RSS moves once warm: the highest per-minute peak over the lowest, over the
    /// whole minutes of load after the first (1.0 is flat; 0 when there are none).
    pub rss_spread: f64,
}

/// One minute of the run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Minute {
    pub minute: usize,
    pub cached_gets: usize,
    pub cached_get_p99_ms: f64,
    pub peak_rss_mib: f64,
}

impl SoakReport {
    /// The first broken promise, if any, in one line.
    pub fn fault(&self) -> Option<String> {
        if self.jobs_lost > 0 {
            return Some(format!(
                "{} of {} accepted jobs were lost",
                self.jobs_lost, self.jobs_accepted
            ));
        }
        if self.cancels_undone > 0 {
            return Some(format!(
                "{} of {} cancelled jobs ended otherwise",
                self.cancels_undone, self.jobs_cancelled
            ));
        }
        if self.wrong_bytes + self.wrong_keys > 0 {
            return Some(format!(
                "{} fetches served other bytes for a key and {} submissions another key",
                self.wrong_bytes, self.wrong_keys
            ));
        }
        let (what, count) = self.unexpected.iter().next()?;
        Some(format!(
            "{count} unexpected answers `{what}` (and {} kinds in all)",
            self.unexpected.len()
        ))
    }
}

/// The server process and where it listens.
struct Server {
    child: Child,
    listen: String,
    base: String,
}

/// A submitted mesh: its bytes, its key as computed here, and its job.
struct Submitted {
    obj: Vec<u8>,
    key: String,
    job: String,
}

/// What the clients share.
#[derive(Default)]
struct Shared {
    submitted: Vec<Submitted>,
    /// Indices into `submitted` not seen ended yet.
    pending: Vec<usize>,
    /// Indices into `submitted` that a DELETE cancelled (answered 200), and those seen
    /// ended otherwise than cancelled: a job in both is a cancel undone, whichever came first.
    cancelled: HashSet<usize>,
    ended_otherwise: HashSet<usize>,
    /// Keys of done jobs, and the BLAKE3 of the GLB first fetched for each.
    done: Vec<String>,
    hashes: HashMap<String, blake3::Hash>,
    report: SoakReport,
    /// (seconds since start, ms) of each cached GET answered 200.
    gets: Vec<(f64, f64)>,
    /// (seconds since start, KiB).
    rss: Vec<(f64, u64)>,
    next_mesh: usize,
}

/// Most submitted jobs not seen ended before the clients stop submitting new meshes.
const OPEN_JOBS: usize = 32;

/// Largest body the soaked server takes: oversized uploads are just past it.
const MAX_BODY: usize = 1 << 20;

/// Runs the soak; Err only when the server cannot be started.
pub fn soak(options: &SoakOptions) -> Result<SoakReport, String> {
    std::fs::create_dir_all(&options.dir).map_err(|e| format!("cannot create {}: {e}", options.dir.display()))?;
    let tokens = options.dir.join("tokens.toml");
    let _ = std::fs::remove_file(&tokens);
    let (token, entry) = auth::new_token("soak", &[Scope::Read, Scope::Cook])?;
    auth::append(&tokens, entry)?;
    let settings = crate::config::load(None, &[]).map_err(|e| e.to_string())?;
    let mut nodes = Nodes {
        server: start(options, &tokens, "127.0.0.1:0")?,
        workers: Vec::new(),
        kills: 0,
    };
    for k in 0..options.worker_nodes {
        nodes.workers.push(start_worker(options, k)?);
    }
    let shared = Mutex::new(Shared::default());
    let base = Mutex::new(nodes.server.base.clone());
    let stop = AtomicBool::new(false);
    let started = Instant::now();
    std::thread::scope(|scope| {
        for seed in 0..options.clients {
            let (shared, base, stop, token, settings) = (&shared, &base, &stop, &token, &settings);
            scope.spawn(move || {
                let client = Client::new(token, settings, seed as u64);
                while !stop.load(Ordering::Relaxed) {
                    let base = base.lock().unwrap().clone();
                    client.act(&base, shared, started);
                }
            });
        }
        let mut last_restart = Instant::now();
        while started.elapsed() < options.duration {
            std::thread::sleep(Duration::from_millis(500));
            if let Some(kib) = rss_kib(nodes.server.child.id()) {
                shared.lock().unwrap().rss.push((started.elapsed().as_secs_f64(), kib));
            }
            if last_restart.elapsed() >= options.restart_every && started.elapsed() < options.duration {
                let restarted = nodes.restart_next(options, &tokens);
                let mut shared = shared.lock().unwrap();
                match restarted {
                    Err(e) => {
                        stop.store(true, Ordering::Relaxed);
                        return Err(e);
                    }
                    Ok(true) => {
                        *base.lock().unwrap() = nodes.server.base.clone();
                        shared.report.restarts += 1;
                    }
                    Ok(false) => shared.report.worker_restarts += 1,
                }
                last_restart = Instant::now();
            }
        }
        stop.store(true, Ordering::Relaxed);
        Ok(())
    })?;
    let client = Client::new(&token, &settings, u64::MAX);
    client.drain(&nodes.server.base, &shared, Duration::from_secs(300));
    for child in nodes.all() {
        let _ = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
        let _ = child.wait();
    }
    let mut shared = shared.into_inner().unwrap();
    shared.report.seconds = started.elapsed().as_secs_f64();
    shared.report.minutes = minutes(&shared.gets, &shared.rss);
    let loaded_minutes = (options.duration.as_secs_f64() / 60.0) as usize;
    shared.report.rss_spread = rss_spread(&shared.report.minutes, loaded_minutes);
    Ok(shared.report)
}

/// Starts `serve` on `listen` and waits for its ready line.
fn start(options: &SoakOptions, tokens: &Path, listen: &str) -> Result<Server, String> {
    let sets = [
        "service.auth=tokens".to_string(),
        format!("service.tokens_file={}", tokens.display()),
        format!("service.max_body_bytes={MAX_BODY}"),
        "service.token_submissions_per_s=1000".into(),
        "service.token_submission_burst=1000".into(),
    ];
    let data = options.dir.join("data");
    let mut args = [
        OsStr::new("serve"),
        "--listen".as_ref(),
        listen.as_ref(),
        "--data-dir".as_ref(),
        data.as_os_str(),
    ]
    .to_vec();
    if options.worker_nodes > 0 {
        args.push("--no-workers".as_ref());
    }
    let (child, address) = spawn_node(options, &args, &sets, ("the server", "server"), "listening on ")?;
    Ok(Server {
        base: format!("http://{address}"),
        listen: address,
        child,
    })
}

/// Starts worker node `k` and waits for its ready line.
fn start_worker(options: &SoakOptions, k: usize) -> Result<Child, String> {
    let (what, log) = (format!("worker node {k}"), format!("worker-{k}"));
    let (child, _) = spawn_node(options, &["worker".as_ref()], &[], (&what, &log), "worker ready")?;
    Ok(child)
}

/// Runs this binary with `args`, the settings `sets` and then the soak's own, its stderr
/// appended to `<log>.log`, and waits for the first line it prints, which must start with
/// `ready`: returns it with the rest of that line. A node that prints another is killed.
fn spawn_node(
    options: &SoakOptions,
    args: &[&OsStr],
    sets: &[String],
    (what, log): (&str, &str),
    ready: &str,
) -> Result<(Child, String), String> {
    let log = options.dir.join(format!("{log}.log"));
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)
        .map_err(|e| format!("cannot write {}: {e}", log.display()))?;
    let mut command = Command::new(&options.binary);
    command.args(args);
    for set in sets.iter().chain(&options.server_settings) {
        command.args(["--set", set]);
    }
    let mut child = command
        .stdout(Stdio::piped())
        .stderr(file)
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", options.binary.display()))?;
    let mut line = String::new();
    let _ = BufReader::new(child.stdout.take().expect("piped")).read_line(&mut line);
    match line.trim().strip_prefix(ready) {
        Some(rest) => Ok((child, rest.trim().to_string())),
        None => {
            let _ = child.kill();
            let _ = child.wait();
            Err(format!("{what} did not start (see {})", log.display()))
        }
    }
}

/// The soaked processes. Any still running when the soak ends early are killed.
struct Nodes {
    server: Server,
    workers: Vec<Child>,
    /// SIGKILLs so far.
    kills: usize,
}

impl Nodes {
    fn all(&mut self) -> impl Iterator<Item = &mut Child> {
        self.workers.iter_mut().chain([&mut self.server.child])
    }

    /// Kills the next node with SIGKILL and starts it again: the server (then true), then each
    /// worker node, in turn.
    fn restart_next(&mut self, options: &SoakOptions, tokens: &Path) -> Result<bool, String> {
        let victim = self.kills % (1 + self.workers.len());
        self.kills += 1;
        let child = match victim {
            0 => &mut self.server.child,
            k => &mut self.workers[k - 1],
        };
        let _ = child.kill();
        let _ = child.wait();
        match victim {
            0 => self.server = start(options, tokens, &self.server.listen)?,
            k => self.workers[k - 1] = start_worker(options, k - 1)?,
        }
        Ok(victim == 0)
    }
}

impl Drop for Nodes {
    fn drop(&mut self) {
        for child in self.all() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// A process's resident memory, from /proc.
fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Cached GETs and their p99, and the peak RSS, in each minute.
fn minutes(gets: &[(f64, f64)], rss: &[(f64, u64)]) -> Vec<Minute> {
    let last = gets
        .iter()
        .map(|g| g.0)
        .chain(rss.iter().map(|r| r.0))
        .fold(0.0, f64::max);
    (0..=(last / 60.0) as usize)
        .map(|minute| {
            let within = |t: f64| (t / 60.0) as usize == minute;
            let mut ms: Vec<f64> = gets.iter().filter(|g| within(g.0)).map(|g| g.1).collect();
            ms.sort_by(f64::total_cmp);
            let p99 = ms
                .get(((ms.len() as f64 * 0.99).ceil() as usize).saturating_sub(1))
                .copied();
            let peak = rss.iter().filter(|r| within(r.0)).map(|r| r.1).max().unwrap_or(0);
            Minute {
                minute: minute + 1,
                cached_gets: ms.len(),
                cached_get_p99_ms: p99.unwrap_or(0.0),
                peak_rss_mib: peak as f64 / 1024.0,
            }
        })
        .collect()
}

/// The highest per-minute peak RSS over the lowest, in minutes 2 to `loaded` (the first warms
/// up; those after `loaded` only wait for the last jobs).
fn rss_spread(minutes: &[Minute], loaded: usize) -> f64 {
    let warm: Vec<f64> = minutes
        .iter()
        .filter(|m| (2..=loaded).contains(&m.minute))
        .map(|m| m.peak_rss_mib)
        .collect();
    let (low, high) = warm
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
    if warm.is_empty() || low <= 0.0 { 0.0 } else { high / low }
}

/// One client thread: its connection, token and dice.
struct Client<'a> {
    agent: ureq::Agent,
    token: &'a str,
    settings: &'a Settings,
    dice: std::cell::RefCell<fastrand::Rng>,
}

/// An answer: status and body, or None when none came.
type Answer = Option<(u16, Vec<u8>)>;

impl<'a> Client<'a> {
    fn new(token: &'a str, settings: &'a Settings, seed: u64) -> Client<'a> {
        let agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(30)))
            .build()
            .into();
        Client {
            agent,
            token,
            settings,
            dice: std::cell::RefCell::new(fastrand::Rng::with_seed(seed)),
        }
    }

    /// A number below `n`, at random.
    fn pick(&self, n: usize) -> usize {
        self.dice.borrow_mut().usize(0..n)
    }

    fn send(&self, method: &str, url: &str, token: Option<&str>, content_type: &str, body: &[u8]) -> Answer {
        let authorization = token.map(|t| format!("Bearer {t}"));
        let result = if method == "POST" {
            let mut request = self.agent.post(url).header("Content-Type", content_type);
            if let Some(value) = &authorization {
                request = request.header("Authorization", value);
            }
            if body.len() > MAX_BODY {
                // The server closes it after its 413: it must not go back to the pool.
                request = request.header("Connection", "close");
            }
            request.send(body)
        } else {
            let mut request = match method {
                "DELETE" => self.agent.delete(url),
                _ => self.agent.get(url),
            };
            if let Some(value) = &authorization {
                request = request.header("Authorization", value);
            }
            request.call()
        };
        let mut response = result.ok()?;
        let status = response.status().as_u16();
        let body = response.body_mut().with_config().limit(64 << 20).read_to_vec().ok()?;
        (status != 503).then_some((status, body))
    }

    /// One request of a kind drawn at random, checked.
    fn act(&self, base: &str, shared: &Mutex<Shared>, started: Instant) {
        // New meshes only while few jobs are open: the workers keep up, and the queue never
        // fills to refuse the rest of the mix.
        let open_jobs = shared.lock().unwrap().pending.len();
        let kind = match self.pick(100) {
            0..25 if open_jobs < OPEN_JOBS => "new_mesh",
            0..25 => "cached_get",
            25..40 => "duplicate",
            40..55 => "poll",
            55 => "cancel",
            56..80 => "cached_get",
            80..88 => "malformed",
            88..92 => "oversized",
            _ => "unauthenticated",
        };
        *shared.lock().unwrap().report.requests.entry(kind.into()).or_default() += 1;
        let outcome = match kind {
            "new_mesh" => self.new_mesh(base, shared),
            "duplicate" => self.duplicate(base, shared),
            "poll" => self.poll(base, shared),
            "cancel" => self.cancel(base, shared),
            "cached_get" => self.cached_get(base, shared, started),
            "malformed" => {
                let garbage: Vec<u8> = (0..1 + self.pick(4096)).map(|_| self.pick(256) as u8).collect();
                let answer = self.send(
                    "POST",
                    &format!("{base}/v1/cook"),
                    Some(self.token),
                    "model/gltf-binary",
                    &garbage,
                );
                Outcome::of(answer, |status| matches!(status, 400 | 413 | 415 | 422))
            }
            "oversized" => {
                let body = vec![b'v'; MAX_BODY + 1];
                let answer = self.send("POST", &format!("{base}/v1/cook"), Some(self.token), "model/obj", &body);
                Outcome::of(answer, |status| status == 413)
            }
            _ => {
                let token = ["", "not-a-token"][self.pick(2)];
                let answer = self.send(
                    "GET",
                    &format!("{base}/v1/jobs/x"),
                    Some(token).filter(|t| !t.is_empty()),
                    "",
                    b"",
                );
                Outcome::of(answer, |status| status == 401)
            }
        };
        {
            let report = &mut shared.lock().unwrap().report;
            match outcome {
                Outcome::Expected => {}
                Outcome::Unavailable => *report.unavailable.entry(kind.into()).or_default() += 1,
                Outcome::Busy => report.busy += 1,
                Outcome::Unexpected(status) => {
                    *report.unexpected.entry(format!("{kind} {status}")).or_default() += 1;
                }
            }
        }
        // As a well-behaved client: no hammering a server that is down or asks for patience.
        if matches!(outcome, Outcome::Unavailable | Outcome::Busy) {
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// A box of a size no other has, as OBJ, and its key.
    fn new_mesh(&self, base: &str, shared: &Mutex<Shared>) -> Outcome {
        let i = {
            let mut shared = shared.lock().unwrap();
            shared.next_mesh += 1;
            shared.next_mesh
        };
        let (x, y, z) = (
            1.0 + i as f64 * 1e-4,
            0.5 + (i % 7) as f64 * 0.1,
            0.25 + (i % 5) as f64 * 0.1,
        );
        let obj = format!(
            "v 0 0 0\nv {x} 0 0\nv 0 {y} 0\nv {x} {y} 0\nv 0 0 {z}\nv {x} 0 {z}\nv 0 {y} {z}\nv {x} {y} {z}\n\
             f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n"
        )
        .into_bytes();
        let limits = self.settings.ingest_limits();
        let mesh = load_bytes(&obj, Format::Obj, None, &limits).expect("a box reads").0;
        let key = crate::key::cache_key(&mesh, &self.settings.cook);
        let answer = self.send("POST", &format!("{base}/v1/cook"), Some(self.token), "model/obj", &obj);
        let Some((status, body)) = answer else {
            return Outcome::Unavailable;
        };
        if status == 429 {
            return Outcome::Busy;
        }
        let reply: serde_json::Value = serde_json::from_slice(&body).unwrap_or_default();
        let (Some(job), Some(served_key)) = (reply["job"].as_str(), reply["key"].as_str()) else {
            return Outcome::Unexpected(status);
        };
        let mut shared = shared.lock().unwrap();
        if served_key != key {
            shared.report.wrong_keys += 1;
        }
        shared.report.jobs_accepted += 1;
        let index = shared.submitted.len();
        shared.submitted.push(Submitted {
            obj,
            key,
            job: job.to_string(),
        });
        shared.pending.push(index);
        if matches!(status, 200 | 202) {
            Outcome::Expected
        } else {
            Outcome::Unexpected(status)
        }
    }

    /// A mesh sent before, again: the same key, cached or joined.
    fn duplicate(&self, base: &str, shared: &Mutex<Shared>) -> Outcome {
        let picked = {
            let shared = shared.lock().unwrap();
            (!shared.submitted.is_empty()).then(|| {
                let s = &shared.submitted[self.pick(shared.submitted.len())];
                (s.obj.clone(), s.key.clone())
            })
        };
        let Some((obj, key)) = picked else {
            return Outcome::Expected;
        };
        let answer = self.send("POST", &format!("{base}/v1/cook"), Some(self.token), "model/obj", &obj);
        if let Some((200 | 202, body)) = &answer {
            let reply: serde_json::Value = serde_json::from_slice(body).unwrap_or_default();
            if reply["key"].as_str() != Some(key.as_str()) {
                shared.lock().unwrap().report.wrong_keys += 1;
            }
        }
        Outcome::of(answer, |status| matches!(status, 200 | 202))
    }

    /// A job not seen ended yet: its index and id.
    fn pick_pending(&self, shared: &Mutex<Shared>) -> Option<(usize, String)> {
        let shared = shared.lock().unwrap();
        (!shared.pending.is_empty()).then(|| {
            let index = shared.pending[self.pick(shared.pending.len())];
            (index, shared.submitted[index].job.clone())
        })
    }

    /// The state of a job not seen ended yet; a done one's key joins the cached GETs.
    fn poll(&self, base: &str, shared: &Mutex<Shared>) -> Outcome {
        let Some((index, job)) = self.pick_pending(shared) else {
            return Outcome::Expected;
        };
        let answer = self.send("GET", &format!("{base}/v1/jobs/{job}"), Some(self.token), "", b"");
        if let Some((200, body)) = &answer {
            self.note_state(shared, index, body);
        }
        Outcome::of(answer, |status| status == 200)
    }

    /// DELETE of a job not seen ended yet: cancelled (200), or it ended first (409).
    fn cancel(&self, base: &str, shared: &Mutex<Shared>) -> Outcome {
        let Some((index, job)) = self.pick_pending(shared) else {
            return Outcome::Expected;
        };
        let answer = self.send("DELETE", &format!("{base}/v1/jobs/{job}"), Some(self.token), "", b"");
        if let Some((200, _)) = &answer {
            let mut shared = shared.lock().unwrap();
            shared.cancelled.insert(index);
            if shared.ended_otherwise.contains(&index) {
                shared.report.cancels_undone += 1;
            }
        }
        Outcome::of(answer, |status| matches!(status, 200 | 409))
    }

    /// Records a job's end from its record: done (its key then served), cancelled or failed.
    fn note_state(&self, shared: &Mutex<Shared>, index: usize, record: &[u8]) {
        let record: serde_json::Value = serde_json::from_slice(record).unwrap_or_default();
        let state = record["state"].as_str().unwrap_or_default();
        if !matches!(state, "done" | "failed") {
            return;
        }
        let mut shared = shared.lock().unwrap();
        let Some(slot) = shared.pending.iter().position(|&i| i == index) else {
            return;
        };
        shared.pending.swap_remove(slot);
        if record["attempts"].as_u64() > Some(1) {
            shared.report.jobs_started_again += 1;
        }
        if state == "failed" && record["error"]["code"] == "cancelled" {
            shared.report.jobs_cancelled += 1;
            return;
        }
        shared.ended_otherwise.insert(index);
        if shared.cancelled.contains(&index) {
            shared.report.cancels_undone += 1;
        }
        if state == "done" {
            shared.report.jobs_done += 1;
            let key = shared.submitted[index].key.clone();
            shared.done.push(key);
        } else {
            shared.report.jobs_failed += 1;
        }
    }

    /// The GLB of a done key: 200, and the same bytes each time.
    fn cached_get(&self, base: &str, shared: &Mutex<Shared>, started: Instant) -> Outcome {
        let picked = {
            let shared = shared.lock().unwrap();
            (!shared.done.is_empty()).then(|| shared.done[self.pick(shared.done.len())].clone())
        };
        let Some(key) = picked else {
            return Outcome::Expected;
        };
        let sent = Instant::now();
        let answer = self.send("GET", &format!("{base}/v1/occluders/{key}"), Some(self.token), "", b"");
        let ms = sent.elapsed().as_secs_f64() * 1e3;
        if let Some((200, body)) = &answer {
            self.check_bytes(shared, &key, body);
            shared.lock().unwrap().gets.push((started.elapsed().as_secs_f64(), ms));
        }
        Outcome::of(answer, |status| status == 200)
    }

    fn check_bytes(&self, shared: &Mutex<Shared>, key: &str, glb: &[u8]) {
        let hash = blake3::hash(glb);
        let mut shared = shared.lock().unwrap();
        shared.report.occluders_fetched += 1;
        let first = *shared.hashes.entry(key.to_string()).or_insert(hash);
        if first != hash || !glb.starts_with(b"glTF") {
            shared.report.wrong_bytes += 1;
        }
    }

    /// After the load: waits for every accepted job to end (a job the server does not know, or
    /// one still not ended at `patience`, is lost), and fetches each done key once more.
    fn drain(&self, base: &str, shared: &Mutex<Shared>, patience: Duration) {
        let started = Instant::now();
        loop {
            let pending: Vec<(usize, String)> = {
                let shared = shared.lock().unwrap();
                shared
                    .pending
                    .iter()
                    .map(|&i| (i, shared.submitted[i].job.clone()))
                    .collect()
            };
            if pending.is_empty() || started.elapsed() > patience {
                shared.lock().unwrap().report.jobs_lost += pending.len();
                break;
            }
            for (index, job) in pending {
                match self.send("GET", &format!("{base}/v1/jobs/{job}"), Some(self.token), "", b"") {
                    Some((200, body)) => self.note_state(shared, index, &body),
                    Some((404, _)) => {
                        let mut shared = shared.lock().unwrap();
                        shared.pending.retain(|&i| i != index);
                        shared.report.jobs_lost += 1;
                    }
                    _ => {}
                }
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let done = shared.lock().unwrap().done.clone();
        for key in done {
            match self.send("GET", &format!("{base}/v1/occluders/{key}"), Some(self.token), "", b"") {
                Some((200, glb)) => self.check_bytes(shared, &key, &glb),
                other => {
                    let status = other.map_or(0, |(status, _)| status);
                    *shared
                        .lock()
                        .unwrap()
                        .report
                        .unexpected
                        .entry(format!("final_get {status}"))
                        .or_default() += 1;
                }
            }
        }
    }
}

/// How an answer measured up.
enum Outcome {
    Expected,
    Unavailable,
    Busy,
    Unexpected(u16),
}

impl Outcome {
    fn of(answer: Answer, allowed: impl Fn(u16) -> bool) -> Outcome {
        match answer {
            None => Outcome::Unavailable,
            Some((status, _)) if allowed(status) => Outcome::Expected,
            Some((429, _)) => Outcome::Busy,
            Some((status, _)) => Outcome::Unexpected(status),
        }
    }
}
