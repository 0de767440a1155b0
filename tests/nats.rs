//! The cluster mode on a real `nats-server -js` (Debian package `nats-server`) on a loopback
//! port, with API nodes (`serve --no-workers`) and worker nodes (`worker`) of the real binary:
//! cross-node deduplication and cache, an API node killed, a worker killed mid-job, a job that
//! keeps killing its workers, and nats-server restarted mid-run.
//!
//! Without nats-server on PATH these tests say so and pass, except under CI (`CI=true`), where
//! .ci/run installs it and its absence is a failure.

mod common;
use common::http::*;
use common::torus;
use serde_json::Value;
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// How long a job may go unacknowledged before another worker gets it, in these tests.
const ACK_WAIT: &str = "service.ack_wait_s=2";

struct Nats {
    child: Child,
    port: u16,
    dir: PathBuf,
}

impl Nats {
    /// A JetStream server on a free loopback port with its store in a fresh folder, or None
    /// (saying so) where nats-server is not installed.
    fn start(name: &str) -> Option<Nats> {
        if Command::new("nats-server").arg("--version").output().is_err() {
            assert!(
                std::env::var("CI").is_err(),
                "nats-server is not installed: .ci/run installs the Debian package nats-server"
            );
            eprintln!("nats-server not found: install the Debian package nats-server to run the NATS tests; skipping");
            return None;
        }
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let dir = std::env::temp_dir().join(format!("occluder-cook-nats-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        Some(Nats::spawn(port, dir))
    }

    fn spawn(port: u16, dir: PathBuf) -> Nats {
        let child = Command::new("nats-server")
            .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
            .arg(&dir)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("nats-server starts");
        let start = Instant::now();
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(start.elapsed() < Duration::from_secs(20), "nats-server does not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        Nats { child, port, dir }
    }

    fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// Stops the server (SIGTERM, as a rolling restart does) and starts it again on the same
    /// port and store.
    fn restart(mut self) -> Nats {
        Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        self.child.wait().unwrap();
        let (port, dir) = (self.port, std::mem::take(&mut self.dir));
        std::mem::forget(self);
        Nats::spawn(port, dir)
    }

    fn api(&self, sets: &[&str]) -> Server {
        let url = self.url();
        let mut args = vec!["serve", "--no-workers", "--listen", "127.0.0.1:0", "--nats", &url];
        for s in sets {
            args.extend(["--set", s]);
        }
        Server::spawn(&args, &[])
    }

    fn worker(&self, sets: &[&str]) -> Server {
        let url = self.url();
        let mut args = vec!["worker", "--nats", &url, "--set", "service.workers=1"];
        for s in sets {
            args.extend(["--set", s]);
        }
        Server::spawn(&args, &[])
    }
}

impl Drop for Nats {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Posts a mesh, retrying while the store is unavailable; returns the accepted JSON.
fn submit(base: &str, query: &str, mesh: &[u8]) -> Value {
    let start = Instant::now();
    loop {
        let reply = post(&format!("{base}/v1/cook?format=obj{query}"), None, mesh);
        if reply.status == 202 || reply.status == 200 {
            return reply.json();
        }
        assert_eq!(reply.status, 503, "{}", String::from_utf8_lossy(&reply.body));
        assert!(start.elapsed() < Duration::from_secs(60), "the store stays unavailable");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Waits until the job is running somewhere.
fn wait_running(base: &str, job: &str) {
    let start = Instant::now();
    loop {
        let j = get(&format!("{base}/v1/jobs/{job}"), &[]).json();
        if j["state"] == "running" {
            return;
        }
        assert_eq!(j["state"], "queued", "{j}");
        assert!(start.elapsed() < Duration::from_secs(30), "job {job} never started");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A torus that takes a few seconds to cook at this resolution: long enough to kill its worker.
const SLOW: &str = "&resolution=192";

fn slow_mesh() -> Vec<u8> {
    obj_text(&torus(1.0, 0.4, 40, 20))
}

#[test]
fn two_api_nodes_share_dedup_and_cache_and_outlive_each_other() {
    let Some(nats) = Nats::start("dedup") else { return };
    let (a, b) = (nats.api(&[]), nats.api(&[]));
    let _workers = (nats.worker(&[]), nats.worker(&[]));
    let mesh = small_mesh(7);

    // The same mesh posted to both API nodes at once is one job.
    let (first, second) = std::thread::scope(|s| {
        let one = s.spawn(|| submit(&a.base, "", &mesh));
        let two = s.spawn(|| submit(&b.base, "", &mesh));
        (one.join().unwrap(), two.join().unwrap())
    });
    assert_eq!(first["job"], second["job"], "{first} {second}");
    assert_eq!(first["key"], second["key"]);
    let (job, key) = (first["job"].as_str().unwrap(), first["key"].as_str().unwrap());
    let done = wait_for(&b.base, job, Duration::from_secs(60));
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["attempts"], 1);

    // Both nodes serve the one result, and a repost on either is a cache hit.
    let from_a = get(&format!("{}/v1/occluders/{key}", a.base), &[]);
    let from_b = get(&format!("{}/v1/occluders/{key}", b.base), &[]);
    assert_eq!((from_a.status, from_b.status), (200, 200));
    assert_eq!(from_a.body, from_b.body);
    assert_eq!(&from_a.body[..4], b"glTF");
    let again = post(&format!("{}/v1/cook?format=obj", b.base), None, &mesh);
    assert_eq!(again.status, 200);
    // A job id that no store key can hold is simply no job, not a store failure.
    for id in ["nope", "a.b*c%3E", &"f".repeat(28)] {
        get(&format!("{}/v1/jobs/{id}", a.base), &[]).assert_error(404, "unknown_job");
    }
    assert_eq!(again.json()["job"], job);

    // An API node killed after accepting jobs: they finish, seen through the other node.
    let jobs: Vec<String> = (20..26)
        .map(|i| submit(&a.base, "", &small_mesh(i))["job"].as_str().unwrap().to_string())
        .collect();
    a.kill_9();
    for job in &jobs {
        let done = wait_for(&b.base, job, Duration::from_secs(120));
        assert_eq!(done["state"], "done", "{done}");
    }
    // Every job has left the queue (its ack may trail its done state by a moment).
    let start = Instant::now();
    while get(&format!("{}/healthz", b.base), &[]).json()["queue_depth"] != 0 {
        assert!(start.elapsed() < Duration::from_secs(10), "jobs left on the queue");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_worker_killed_mid_job_hands_it_to_another_which_finishes_it_once() {
    let Some(nats) = Nats::start("killed") else { return };
    let api = nats.api(&[]);
    let first = nats.worker(&[ACK_WAIT]);
    let accepted = submit(&api.base, SLOW, &slow_mesh());
    let (job, key) = (accepted["job"].as_str().unwrap(), accepted["key"].as_str().unwrap());
    wait_running(&api.base, job);
    // Only now a second worker, so that the job was the first one's.
    let _second = nats.worker(&[ACK_WAIT]);
    first.kill_9();

    let done = wait_for(&api.base, job, Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["attempts"], 2, "{done}");
    assert_eq!(done["key"], key);
    let glb = get(&format!("{}/v1/occluders/{key}", api.base), &[]);
    assert_eq!(glb.status, 200);
    // One final state: the job stays done, and a repost is the same job's result.
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(get(&format!("{}/v1/jobs/{job}", api.base), &[]).json(), done);
    let again = post(&format!("{}/v1/cook?format=obj{SLOW}", api.base), None, &slow_mesh());
    assert_eq!((again.status, again.json()["job"].as_str()), (200, Some(job)));
}

#[test]
fn a_job_that_keeps_killing_its_workers_fails_after_max_deliver() {
    let Some(nats) = Nats::start("poison") else { return };
    let api = nats.api(&[]);
    let sets = [ACK_WAIT, "service.max_deliver=1"];
    let first = nats.worker(&sets);
    let accepted = submit(&api.base, SLOW, &slow_mesh());
    let job = accepted["job"].as_str().unwrap();
    wait_running(&api.base, job);
    let _second = nats.worker(&sets);
    first.kill_9();

    let failed = wait_for(&api.base, job, Duration::from_secs(60));
    assert_eq!(failed["state"], "failed", "{failed}");
    assert_eq!(failed["error"]["code"], "worker_lost", "{failed}");
    assert!(failed["error"]["message"].as_str().unwrap().contains("started 1 times"));
    // The poisoned key is free again: a new submission is a new job.
    let again = submit(&api.base, SLOW, &slow_mesh());
    assert_ne!(again["job"], job);
}

#[test]
fn nats_restarted_mid_run_loses_no_job() {
    let Some(nats) = Nats::start("restart") else { return };
    let api = nats.api(&[]);
    let _workers = (nats.worker(&[ACK_WAIT]), nats.worker(&[ACK_WAIT]));
    let mut jobs: Vec<String> = (40..46)
        .map(|i| {
            submit(&api.base, "", &small_mesh(i))["job"]
                .as_str()
                .unwrap()
                .to_string()
        })
        .collect();
    let slow = submit(&api.base, SLOW, &slow_mesh());
    jobs.push(slow["job"].as_str().unwrap().to_string());
    wait_running(&api.base, jobs.last().unwrap());

    let nats = nats.restart();
    // Accepted while the server was away, or just after.
    jobs.push(
        submit(&api.base, "", &small_mesh(47))["job"]
            .as_str()
            .unwrap()
            .to_string(),
    );
    for job in &jobs {
        let done = wait_for(&api.base, job, Duration::from_secs(180));
        assert_eq!(done["state"], "done", "{done}");
        let key = done["key"].as_str().unwrap();
        assert_eq!(get(&format!("{}/v1/occluders/{key}", api.base), &[]).status, 200);
    }
    drop(nats);
}
