//! The cluster mode on a real `nats-server -js` (Debian package `nats-server`) on a loopback
//! port, with API nodes (`serve --no-workers`) and worker nodes (`worker`) of the real binary:
//! cross-node deduplication and cache, an API node killed, a worker killed mid-job, a job that
//! keeps killing its workers, nats-server restarted mid-run, and away longer than a worker's
//! store retries, with the worker kept at its job or stopped meanwhile, a running job cancelled
//! through an API node, and a minute of `soak` with every node killed in turn.
//!
//! The server requires a user and password and speaks TLS only, with a certificate from a CA made
//! for the test: every node signs in and checks the server against that CA.
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
    /// The password, the CA and the server's certificate and key.
    secrets: PathBuf,
}

/// The user the server requires.
const NATS_USER: &str = "occluder";

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
        let secrets = dir.with_extension("secrets");
        std::fs::create_dir_all(&secrets).unwrap();
        let (ca, cert, key) = common::tls::certificate_authority();
        for (file, text) in [
            ("password", format!("{:032x}", fastrand::u128(..))),
            ("ca.pem", ca),
            ("cert.pem", cert),
            ("key.pem", key),
        ] {
            std::fs::write(secrets.join(file), text).unwrap();
        }
        Some(Nats::spawn(port, dir, secrets))
    }

    fn spawn(port: u16, dir: PathBuf, secrets: PathBuf) -> Nats {
        let password = std::fs::read_to_string(secrets.join("password")).unwrap();
        let child = Command::new("nats-server")
            .args([
                "-js",
                "-a",
                "127.0.0.1",
                "-p",
                &port.to_string(),
                "--user",
                NATS_USER,
                "--pass",
            ])
            .arg(password)
            .arg("--tls")
            .arg("--tlscert")
            .arg(secrets.join("cert.pem"))
            .arg("--tlskey")
            .arg(secrets.join("key.pem"))
            .arg("-sd")
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
        Nats {
            child,
            port,
            dir,
            secrets,
        }
    }

    fn url(&self) -> String {
        format!("tls://127.0.0.1:{}", self.port)
    }

    /// The settings that sign a node in and make it check the server's certificate.
    fn credentials(&self) -> [String; 3] {
        [
            format!("service.nats_user={NATS_USER}"),
            format!("service.nats_password_file={}", self.secrets.join("password").display()),
            format!("service.nats_ca_cert={}", self.secrets.join("ca.pem").display()),
        ]
    }

    /// Stops the server (SIGTERM, as a rolling restart does), runs `meanwhile`, and starts it
    /// again on the same port and store.
    fn restart(mut self, meanwhile: impl FnOnce()) -> Nats {
        Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        self.child.wait().unwrap();
        // The nodes' calls meanwhile wait or fail, and no job may be lost.
        meanwhile();
        let (port, dir, secrets) = (
            self.port,
            std::mem::take(&mut self.dir),
            std::mem::take(&mut self.secrets),
        );
        std::mem::forget(self);
        Nats::spawn(port, dir, secrets)
    }

    fn api(&self, sets: &[&str]) -> Server {
        Server::spawn(
            &self.node_args(&["serve", "--no-workers", "--listen", "127.0.0.1:0"], sets),
            &[],
        )
    }

    fn worker(&self, sets: &[&str]) -> Server {
        Server::spawn(&self.node_args(&["worker", "--set", "service.workers=1"], sets), &[])
    }

    /// `command` on this server, signed in, with `sets` besides.
    fn node_args(&self, command: &[&str], sets: &[&str]) -> Vec<String> {
        let mut args: Vec<String> = command.iter().map(|a| a.to_string()).collect();
        args.extend(["--nats".to_string(), self.url()]);
        for set in self
            .credentials()
            .iter()
            .map(String::as_str)
            .chain(sets.iter().copied())
        {
            args.extend(["--set".to_string(), set.to_string()]);
        }
        args
    }
}

impl Drop for Nats {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
        let _ = std::fs::remove_dir_all(&self.secrets);
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

/// Submits the slow mesh and waits until its job is running somewhere: (job, key).
fn slow_job_running(base: &str) -> (String, String) {
    let accepted = submit(base, SLOW, &slow_mesh());
    let [job, key] = ["job", "key"].map(|field| accepted[field].as_str().unwrap().to_string());
    let start = Instant::now();
    loop {
        let j = get(&format!("{base}/v1/jobs/{job}"), &[]).json();
        if j["state"] == "running" {
            return (job, key);
        }
        assert_eq!(j["state"], "queued", "{j}");
        assert!(start.elapsed() < Duration::from_secs(30), "job {job} never started");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits until the job is done and its occluder is served: its record.
fn wait_done_and_served(base: &str, job: &str, limit: Duration) -> Value {
    let done = wait_for(base, job, limit);
    assert_eq!(done["state"], "done", "{done}");
    let key = done["key"].as_str().unwrap();
    assert_eq!(get(&format!("{base}/v1/occluders/{key}"), &[]).status, 200);
    done
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
    let ids: Vec<&str> = jobs.iter().map(String::as_str).chain([job]).collect();
    for limit in [3, 50] {
        assert_lists_newest(&b.base, &ids, limit);
    }
}

#[test]
fn a_worker_killed_mid_job_hands_it_to_another_which_finishes_it_once() {
    let Some(nats) = Nats::start("killed") else { return };
    let api = nats.api(&[]);
    let first = nats.worker(&[ACK_WAIT]);
    let (job, key) = slow_job_running(&api.base);
    // Only now a second worker, so that the job was the first one's.
    let _second = nats.worker(&[ACK_WAIT]);
    first.kill_9();

    let done = wait_done_and_served(&api.base, &job, Duration::from_secs(120));
    assert_eq!(done["attempts"], 2, "{done}");
    assert_eq!(done["key"], key);
    // One final state: the job stays done, and a repost is the same job's result.
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(get(&format!("{}/v1/jobs/{job}", api.base), &[]).json(), done);
    let again = post(&format!("{}/v1/cook?format=obj{SLOW}", api.base), None, &slow_mesh());
    assert_eq!((again.status, again.json()["job"].as_str()), (200, Some(job.as_str())));
}

#[test]
fn a_job_that_keeps_killing_its_workers_fails_after_max_deliver() {
    let Some(nats) = Nats::start("poison") else { return };
    let api = nats.api(&["service.job_retention_s=1"]);
    let sets = [ACK_WAIT, "service.max_deliver=1"];
    let first = nats.worker(&sets);
    let (job, _) = slow_job_running(&api.base);
    let _second = nats.worker(&sets);
    first.kill_9();

    let failed = wait_for(&api.base, &job, Duration::from_secs(60));
    assert_eq!(failed["state"], "failed", "{failed}");
    assert_eq!(failed["error"]["code"], "worker_lost", "{failed}");
    assert!(failed["error"]["message"].as_str().unwrap().contains("started 1 times"));
    // The poisoned key is free again: a new submission is a new job.
    let again = submit(&api.base, SLOW, &slow_mesh());
    assert_ne!(again["job"], job);
    // The failed job's record is collected after service.job_retention_s.
    let started = Instant::now();
    while get(&format!("{}/v1/jobs/{job}", api.base), &[]).status != 404 {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "the failed job's record stays"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn nats_restarted_mid_run_loses_no_job() {
    let Some(nats) = Nats::start("restart") else { return };
    let api = nats.api(&[]);
    let _workers = (nats.worker(&[ACK_WAIT]), nats.worker(&[ACK_WAIT]));
    let mut jobs = vec![slow_job_running(&api.base).0];
    // Small jobs queued behind it: the other worker is working through them as the server goes.
    jobs.extend((40..56).map(|i| {
        submit(&api.base, "", &small_mesh(i))["job"]
            .as_str()
            .unwrap()
            .to_string()
    }));

    let nats = nats.restart(|| std::thread::sleep(Duration::from_secs(1)));
    // Accepted while the server was away, or just after.
    jobs.push(
        submit(&api.base, "", &small_mesh(57))["job"]
            .as_str()
            .unwrap()
            .to_string(),
    );
    for job in &jobs {
        wait_done_and_served(&api.base, job, Duration::from_secs(180));
    }
    drop(nats);
}

#[test]
fn a_worker_keeps_a_job_through_a_store_outage_longer_than_its_retries_and_finishes_it() {
    let Some(nats) = Nats::start("outage") else { return };
    let api = nats.api(&[]);
    // One start allowed: had the job gone back to the queue during the outage (given back, or
    // its ack_wait run out), it would be handed out a second time, to this worker or to the
    // idle one, and fail as worker_lost.
    let sets = [ACK_WAIT, "service.max_deliver=1"];
    let _worker = nats.worker(&sets);
    let (job, key) = slow_job_running(&api.base);
    let _idle = nats.worker(&sets);
    // Away longer than a worker retries a store call (store::PATIENCE, 30 s): the cook ends
    // meanwhile, and storing its result gives up.
    let nats = nats.restart(|| std::thread::sleep(Duration::from_secs(40)));
    let done = wait_done_and_served(&api.base, &job, Duration::from_secs(120));
    assert_eq!(done["attempts"], 1, "{done}");
    assert_eq!(done["key"], key);
    drop(nats);
}

#[test]
fn a_worker_stopped_while_its_store_is_away_leaves_its_job_queued_for_the_next() {
    let Some(nats) = Nats::start("stopped") else { return };
    let api = nats.api(&[]);
    let first = nats.worker(&[ACK_WAIT]);
    let (job, _) = slow_job_running(&api.base);
    // Stopped past store::PATIENCE (30 s) into the outage, when it waits for the store with
    // the job: it must end without the store, and leave the job on the queue.
    let nats = nats.restart(|| {
        std::thread::sleep(Duration::from_secs(35));
        let started = Instant::now();
        assert!(first.terminate().success());
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "the worker took {:?} to stop",
            started.elapsed()
        );
    });
    let _second = nats.worker(&[ACK_WAIT]);
    let done = wait_for(&api.base, &job, Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["attempts"], 2, "{done}");
    drop(nats);
}

#[test]
fn a_node_with_the_wrong_password_or_none_is_refused_at_once() {
    let Some(nats) = Nats::start("refused") else { return };
    let wrong = nats.secrets.join("wrong-password");
    std::fs::write(&wrong, "not-the-password").unwrap();
    let url = nats.url();
    let cases = [
        vec![
            format!("service.nats_user={NATS_USER}"),
            format!("service.nats_password_file={}", wrong.display()),
            format!("service.nats_ca_cert={}", nats.secrets.join("ca.pem").display()),
        ],
        // No credentials at all.
        vec![format!(
            "service.nats_ca_cert={}",
            nats.secrets.join("ca.pem").display()
        )],
    ];
    for sets in cases {
        let mut args = vec!["worker".to_string(), "--nats".into(), url.clone()];
        for set in sets {
            args.extend(["--set".into(), set]);
        }
        let started = Instant::now();
        let out = Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
            .args(&args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(started.elapsed() < Duration::from_secs(10), "not refused at once");
        let last = stderr.lines().last().unwrap_or_default();
        assert!(last.contains("refused this node"), "{stderr}");
        assert!(!stderr.contains("not-the-password"), "a secret was printed: {stderr}");
    }
}

#[test]
fn workers_take_the_tokens_jobs_in_turn() {
    let Some(nats) = Nats::start("turns") else { return };
    let tokens = nats.secrets.join("tokens.toml");
    let token = |name: &str| {
        let (code, stdout, stderr) = common::cli(&[
            "token",
            "new",
            "--name",
            name,
            "--scopes",
            "read,cook",
            "--file",
            tokens.to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{stderr}");
        stdout.trim().to_string()
    };
    let (busy, calm) = (token("busy"), token("calm"));
    let tokens_file = format!("service.tokens_file={}", tokens.display());
    let api = nats.api(&["service.auth=tokens", &tokens_file]);
    let call = |method: &str, path: &str, token: &str, body: &[u8]| {
        let url = format!("{}{path}", api.base);
        let authorization = format!("Bearer {token}");
        let reply = match method {
            "POST" => reply(
                agent()
                    .post(&url)
                    .header("Authorization", &authorization)
                    .header("Content-Type", "model/obj")
                    .send(body),
            ),
            _ => reply(agent().get(&url).header("Authorization", &authorization).call()),
        };
        assert_eq!(reply.status / 100, 2, "{}", String::from_utf8_lossy(&reply.body));
        reply.json()
    };
    // Queued before any worker runs: busy's twenty, then calm's one.
    let busy_jobs: Vec<String> = (0..20)
        .map(|i| {
            call("POST", "/v1/cook", &busy, &small_mesh(i))["job"]
                .as_str()
                .unwrap()
                .to_string()
        })
        .collect();
    let calm_job = call("POST", "/v1/cook", &calm, &small_mesh(100))["job"]
        .as_str()
        .unwrap()
        .to_string();
    let _worker = nats.worker(&[]);
    let started = Instant::now();
    let calm_done = loop {
        let job = call("GET", &format!("/v1/jobs/{calm_job}"), &calm, b"");
        if job["state"] == "done" {
            break job;
        }
        assert!(started.elapsed() < Duration::from_secs(120), "{job}");
        std::thread::sleep(Duration::from_millis(20));
    };
    let done_before = busy_jobs
        .iter()
        .map(|id| call("GET", &format!("/v1/jobs/{id}"), &busy, b""))
        .filter(|job| job["state"] == "done" && job["updated_ms"].as_u64() < calm_done["updated_ms"].as_u64())
        .count();
    assert!(
        done_before <= 2,
        "{done_before} of busy's jobs finished before calm's one"
    );
}

#[test]
fn a_running_job_cancelled_through_another_node_stops_and_stays_cancelled() {
    let Some(nats) = Nats::start("cancel") else { return };
    let api = nats.api(&[]);
    // The default ack_wait: between the worker's reads of the record every ack_wait / 3 (10 s,
    // longer than the cook), it meets the record only where it writes its progress.
    let _worker = nats.worker(&[]);
    let (job, key) = slow_job_running(&api.base);
    let url = format!("{}/v1/jobs/{job}", api.base);
    let cancelled = reply(agent().delete(&url).call());
    assert_eq!(cancelled.status, 200, "{}", String::from_utf8_lossy(&cancelled.body));
    let started = Instant::now();
    let ended = loop {
        let j = get(&url, &[]).json();
        assert!(started.elapsed() < Duration::from_secs(60), "{j}");
        if j["state"] != "failed" {
            panic!("the cancelled job went back to {j}");
        }
        // Stopped: the worker has taken it off the queue.
        if get(&format!("{}/healthz", api.base), &[]).json()["queue_depth"] == 0 {
            break j;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    println!(
        "the worker let go of the cancelled job {:.2} s after its DELETE",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(ended["error"]["code"], "cancelled", "{ended}");
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(get(&url, &[]).json(), ended);
    assert_eq!(get(&format!("{}/v1/occluders/{key}", api.base), &[]).status, 404);
    let next = submit(&api.base, "", &small_mesh(60));
    let done = wait_for(&api.base, next["job"].as_str().unwrap(), Duration::from_secs(60));
    assert_eq!(done["state"], "done", "{done}");
}

/// `soak --worker-nodes 2` on this server: a minute of mixed load (cancels included) on an API
/// node and two worker nodes, each killed with SIGKILL in turn, and still nothing lost or undone.
#[test]
fn a_minute_of_soak_on_a_cluster_whose_nodes_are_killed_in_turn_loses_nothing() {
    let Some(nats) = Nats::start("soak") else { return };
    let sets: Vec<String> = [format!("service.nats_url={}", nats.url()), ACK_WAIT.to_string()]
        .into_iter()
        .chain(nats.credentials())
        .flat_map(|set| ["--set".to_string(), set])
        .collect();
    let mut args = vec!["--restart-every", "12s", "--worker-nodes", "2"];
    args.extend(sets.iter().map(String::as_str));
    let report = common::soak_kept_its_promises("nats", &args);
    assert!(report["restarts"].as_u64() >= Some(1), "{report}");
    assert!(report["worker_restarts"].as_u64() >= Some(2), "{report}");
}
