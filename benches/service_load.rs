//! Load on the real server binary over loopback (run with `cargo bench --bench service_load`),
//! in each deployment mode side by side, one after another in one run:
//!
//! - `sled`: one `serve` process with `service.workers` 1, then 2;
//! - `nats`: a `nats-server -js`, one API node (`serve --no-workers`) and 1, then 2, worker
//!   processes (`worker`, one job at a time each).
//!
//! In each mode: 200 distinct small cook jobs submitted at once from 64 connections (time until
//! all are done, jobs per second, failed and lost jobs); 1,000 duplicate submissions of a cached
//! mesh; 1,000 cached `GET /v1/occluders/{key}` through the API node; and, where `wrk` is
//! installed, 10 s of cached GETs at 64 connections for the server's own rate and p99.
//! The load generator shares the machine's cores with the nodes, as on a studio's CI box.
//!
//! Then cached GETs with a bearer token (`service.auth = "tokens"`), over plain HTTP and over
//! HTTPS (a certificate from a CA made for the run), from the same threads and from wrk.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[path = "../tests/common/tls.rs"]
mod tls;
use tls::certificate_authority;

const CONNECTIONS: usize = 64;

fn agent() -> ureq::Agent {
    agent_trusting(None)
}

/// An agent that trusts the CA in `ca_pem`, if given, in place of the public roots.
fn agent_trusting(ca_pem: Option<&str>) -> ureq::Agent {
    let tls = ca_pem.map_or_else(ureq::tls::TlsConfig::default, |pem| {
        occluder_cook::service::client::trusting(pem.as_bytes()).expect("the run's own CA parses")
    });
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(300)))
        .tls_config(tls)
        .build()
        .into()
}

/// A closed box a little different for each `i`, as OBJ.
fn mesh(i: usize) -> Vec<u8> {
    let (x, y, z) = (1.0 + i as f32 * 0.001, 0.7, 0.4);
    format!(
        "v 0 0 0\nv {x} 0 0\nv 0 {y} 0\nv {x} {y} 0\nv 0 0 {z}\nv {x} 0 {z}\nv 0 {y} {z}\nv {x} {y} {z}\n\
         f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n"
    )
    .into_bytes()
}

/// Runs `count` requests over `CONNECTIONS` threads; returns (latencies, errors, wall time).
fn hammer(count: usize, request: impl Fn(&ureq::Agent, usize) -> bool + Sync) -> (Vec<Duration>, usize, Duration) {
    hammer_trusting(None, count, request)
}

/// [`hammer`] with agents that trust `ca_pem`.
fn hammer_trusting(
    ca_pem: Option<&str>,
    count: usize,
    request: impl Fn(&ureq::Agent, usize) -> bool + Sync,
) -> (Vec<Duration>, usize, Duration) {
    let next = AtomicUsize::new(0);
    let errors = AtomicUsize::new(0);
    let latencies = Mutex::new(Vec::with_capacity(count));
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..CONNECTIONS {
            s.spawn(|| {
                let agent = agent_trusting(ca_pem);
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    if i >= count {
                        break;
                    }
                    let t = Instant::now();
                    let ok = request(&agent, i);
                    let elapsed = t.elapsed();
                    latencies.lock().unwrap().push(elapsed);
                    errors.fetch_add(usize::from(!ok), Ordering::SeqCst);
                }
            });
        }
    });
    (latencies.into_inner().unwrap(), errors.into_inner(), start.elapsed())
}

/// Whether the reply is 200 with its body read whole.
fn ok_200(reply: Result<ureq::http::Response<ureq::Body>, ureq::Error>) -> bool {
    match reply {
        Ok(mut r) => r.status() == 200 && r.body_mut().read_to_vec().is_ok(),
        Err(_) => false,
    }
}

fn percentile(latencies: &mut [Duration], p: f64) -> Duration {
    latencies.sort();
    latencies[((latencies.len() as f64 * p).ceil() as usize).clamp(1, latencies.len()) - 1]
}

fn report(name: &str, mut latencies: Vec<Duration>, errors: usize, wall: Duration) {
    let n = latencies.len();
    println!(
        "{name}: {n} requests in {:.2} s = {:.0}/s, p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms, errors {errors}",
        wall.as_secs_f64(),
        n as f64 / wall.as_secs_f64(),
        percentile(&mut latencies, 0.5).as_secs_f64() * 1e3,
        percentile(&mut latencies, 0.99).as_secs_f64() * 1e3,
        percentile(&mut latencies, 1.0).as_secs_f64() * 1e3,
    );
}

/// One deployment under test: its processes (killed on drop) and the API's address.
struct Deployment {
    processes: Vec<Child>,
    base: String,
    dirs: Vec<PathBuf>,
}

impl Drop for Deployment {
    fn drop(&mut self) {
        for p in self.processes.iter_mut().rev() {
            let _ = Command::new("kill").args(["-TERM", &p.id().to_string()]).status();
            let _ = p.wait();
        }
        for d in &self.dirs {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// Runs the binary and waits for its ready line; returns the process and that line.
fn spawn(args: &[&str]) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
        .args(args)
        .args(["--set", "service.max_queue=1000"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("the binary starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, line.trim().to_string())
}

fn api_base(ready: &str) -> String {
    format!("http://{}", ready.trim_start_matches("listening on "))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("occluder-cook-load-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn sled(workers: usize) -> Deployment {
    let data = scratch(&format!("sled{workers}"));
    let workers = format!("service.workers={workers}");
    let (server, ready) = spawn(&[
        "serve",
        "--listen",
        "127.0.0.1:0",
        "--data-dir",
        data.to_str().unwrap(),
        "--set",
        &workers,
    ]);
    Deployment {
        processes: vec![server],
        base: api_base(&ready),
        dirs: vec![data],
    }
}

/// A nats-server, an API node and `workers` worker processes; None without nats-server.
fn nats(workers: usize) -> Option<Deployment> {
    let store = scratch(&format!("nats{workers}"));
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .ok()?
        .local_addr()
        .ok()?
        .port();
    let server = Command::new("nats-server")
        .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
        .arg(&store)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .ok()?;
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        std::thread::sleep(Duration::from_millis(50));
    }
    let url = format!("nats://127.0.0.1:{port}");
    let mut processes = vec![server];
    let (api, ready) = spawn(&["serve", "--no-workers", "--listen", "127.0.0.1:0", "--nats", &url]);
    processes.push(api);
    for _ in 0..workers {
        processes.push(spawn(&["worker", "--nats", &url, "--set", "service.workers=1"]).0);
    }
    Some(Deployment {
        processes,
        base: api_base(&ready),
        dirs: vec![store],
    })
}

/// The figures of one mode.
struct Row {
    mode: String,
    all_done_s: f64,
    failed: usize,
    lost: usize,
    dup_p99_ms: f64,
    get_p99_ms: f64,
    wrk: Option<(f64, String)>,
}

fn measure(mode: &str, base: &str, data: &Path) -> Row {
    println!("== {mode}: API at {base}, {CONNECTIONS} connections");
    // 1. 200 distinct jobs at once.
    let jobs = Arc::new(Mutex::new(Vec::new()));
    let submitted = Instant::now();
    let (latencies, errors, wall) = hammer(200, |agent, i| {
        let reply = agent
            .post(&format!("{base}/v1/cook"))
            .header("Content-Type", "model/obj")
            .send(&mesh(i)[..]);
        match reply {
            Ok(mut r) if r.status() == 202 => {
                let body: serde_json::Value = serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
                jobs.lock().unwrap().push(body["job"].as_str().unwrap().to_string());
                true
            }
            _ => false,
        }
    });
    report("submit 200 distinct jobs", latencies, errors, wall);
    let jobs = jobs.lock().unwrap().clone();
    let agent = agent();
    let mut done = 0;
    let mut failed = 0;
    for job in &jobs {
        loop {
            let mut r = agent.get(&format!("{base}/v1/jobs/{job}")).call().unwrap();
            let body: serde_json::Value = serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
            match body["state"].as_str() {
                Some("done") => done += 1,
                Some("failed") => failed += 1,
                _ => {
                    std::thread::sleep(Duration::from_millis(20));
                    continue;
                }
            }
            break;
        }
    }
    let all_done = submitted.elapsed();
    let lost = 200 - done - failed;
    println!(
        "200 jobs: {done} done, {failed} failed, {lost} lost, all finished {:.2} s after submission ({:.1} jobs/s)",
        all_done.as_secs_f64(),
        200.0 / all_done.as_secs_f64()
    );

    // 2. Duplicate submissions of a cached mesh.
    let cached = mesh(0);
    let (mut dup, errors, wall) = hammer(1000, |agent, _| {
        let reply = agent
            .post(&format!("{base}/v1/cook"))
            .header("Content-Type", "model/obj")
            .send(&cached[..]);
        ok_200(reply)
    });
    let dup_p99_ms = percentile(&mut dup, 0.99).as_secs_f64() * 1e3;
    report("duplicate submission of a cached mesh", dup, errors, wall);

    // 3. Cached GETs.
    let mut r = agent
        .post(&format!("{base}/v1/cook"))
        .header("Content-Type", "model/obj")
        .send(&cached[..])
        .unwrap();
    let body: serde_json::Value = serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
    let url = format!("{base}{}", body["result_url"].as_str().unwrap());
    let (mut gets, errors, wall) = hammer(1000, |agent, _| ok_200(agent.get(&url).call()));
    let get_p99_ms = percentile(&mut gets, 0.99).as_secs_f64() * 1e3;
    report("cached GET /v1/occluders/{key}", gets, errors, wall);
    // wrk drives far more load than these threads can: the server's own rate and latency.
    std::fs::create_dir_all(data).unwrap();
    let script = data.join("post.lua");
    let body = String::from_utf8(cached.clone()).unwrap();
    std::fs::write(
        &script,
        format!("wrk.method = \"POST\"\nwrk.headers[\"Content-Type\"] = \"model/obj\"\nwrk.body = {body:?}\n"),
    )
    .unwrap();
    let wrk_get = wrk("cached GET /v1/occluders/{key}", &[&url]).and_then(|text| wrk_figures(&text));
    wrk(
        "duplicate POST /v1/cook of a cached mesh",
        &["-s", script.to_str().unwrap(), &format!("{base}/v1/cook")],
    );
    Row {
        mode: mode.to_string(),
        all_done_s: all_done.as_secs_f64(),
        failed,
        lost,
        dup_p99_ms,
        get_p99_ms,
        wrk: wrk_get,
    }
}

/// Cached GETs with a read token from a sled server with `service.auth = "tokens"`, over
/// HTTPS when `tls`: (mode, ureq p99 ms, wrk figures).
fn measure_with_token(tls: bool) -> (String, f64, Option<(f64, String)>) {
    let mode = if tls { "sled, token, HTTPS" } else { "sled, token, HTTP" };
    let data = scratch(if tls { "token-tls" } else { "token" });
    std::fs::create_dir_all(&data).unwrap();
    let tokens = data.join("tokens.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
        .args(["token", "new", "--name", "bench", "--scopes", "read,cook", "--file"])
        .arg(&tokens)
        .output()
        .unwrap();
    let token = String::from_utf8(out.stdout).unwrap().trim().to_string();
    let mut sets = vec![
        "service.auth=tokens".to_string(),
        format!("service.tokens_file={}", tokens.display()),
    ];
    let ca = tls.then(|| {
        let (ca, cert, key) = certificate_authority();
        std::fs::write(data.join("cert.pem"), cert).unwrap();
        std::fs::write(data.join("key.pem"), key).unwrap();
        sets.push(format!("service.tls_cert={}", data.join("cert.pem").display()));
        sets.push(format!("service.tls_key={}", data.join("key.pem").display()));
        ca
    });
    let mut args = vec!["serve", "--listen", "127.0.0.1:0", "--data-dir", data.to_str().unwrap()];
    for set in &sets {
        args.extend(["--set", set]);
    }
    let (server, ready) = spawn(&args);
    let base = api_base(&ready).replace("http://", if tls { "https://" } else { "http://" });
    let deployment = Deployment {
        processes: vec![server],
        base,
        dirs: vec![data],
    };
    let authorization = format!("Bearer {token}");
    let agent = agent_trusting(ca.as_deref());
    let mut r = agent
        .post(&format!("{}/v1/cook", deployment.base))
        .header("Content-Type", "model/obj")
        .header("Authorization", &authorization)
        .send(&mesh(0)[..])
        .unwrap();
    let body: serde_json::Value = serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
    let job = body["job"].as_str().unwrap();
    while !agent
        .get(&format!("{}/v1/jobs/{job}", deployment.base))
        .header("Authorization", &authorization)
        .call()
        .unwrap()
        .body_mut()
        .read_to_string()
        .unwrap()
        .contains("\"done\"")
    {
        std::thread::sleep(Duration::from_millis(20));
    }
    let url = format!("{}{}", deployment.base, body["result_url"].as_str().unwrap());
    println!("== {mode}: {url}");
    let (mut gets, errors, wall) = hammer_trusting(ca.as_deref(), 1000, |agent, _| {
        ok_200(agent.get(&url).header("Authorization", &authorization).call())
    });
    let p99 = percentile(&mut gets, 0.99).as_secs_f64() * 1e3;
    report("cached GET with a token", gets, errors, wall);
    let header = format!("Authorization: {authorization}");
    let wrk_get = wrk(&format!("{mode}, cached GET"), &["-H", &header, &url]).and_then(|text| wrk_figures(&text));
    (mode.to_string(), p99, wrk_get)
}

/// Runs wrk for 10 s at `CONNECTIONS` with `args`; its output, None where it is not installed.
fn wrk(what: &str, args: &[&str]) -> Option<String> {
    match Command::new("wrk")
        .args(["-t2", &format!("-c{CONNECTIONS}"), "-d10s", "--latency"])
        .args(args)
        .output()
    {
        Ok(out) => {
            let text = String::from_utf8_lossy(&out.stdout).into_owned();
            println!("wrk, {what}:\n{text}");
            Some(text)
        }
        Err(_) => {
            println!("wrk not installed (apt-get install wrk): {what} not measured");
            None
        }
    }
}

/// Requests per second and the 99th percentile, from wrk's `--latency` output.
fn wrk_figures(text: &str) -> Option<(f64, String)> {
    let rate = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("Requests/sec:"))?
        .trim()
        .parse()
        .ok()?;
    let p99 = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("99%"))?
        .trim()
        .to_string();
    Some((rate, p99))
}

fn main() {
    let mut rows = Vec::new();
    for workers in [1, 2] {
        let deployment = sled(workers);
        rows.push(measure(
            &format!("sled, 1 process, {workers} workers"),
            &deployment.base,
            &deployment.dirs[0],
        ));
    }
    for workers in [1, 2] {
        let Some(deployment) = nats(workers) else {
            println!("nats-server not installed (apt-get install nats-server): the NATS modes are not measured");
            break;
        };
        rows.push(measure(
            &format!("nats, API node + {workers} worker processes"),
            &deployment.base,
            &deployment.dirs[0],
        ));
    }
    println!(
        "\n{:<42} {:>8} {:>7} {:>6} {:>5} {:>12} {:>12} {:>11} {:>9}",
        "mode", "200 jobs", "jobs/s", "failed", "lost", "dup POST p99", "GET p99", "wrk GET/s", "wrk p99"
    );
    for r in &rows {
        let (rate, p99) = r
            .wrk
            .as_ref()
            .map_or(("-".to_string(), "-".to_string()), |(rate, p99)| {
                (format!("{rate:.0}"), p99.clone())
            });
        println!(
            "{:<42} {:>7.1}s {:>7.2} {:>6} {:>5} {:>9.2} ms {:>9.2} ms {:>11} {:>9}",
            r.mode,
            r.all_done_s,
            200.0 / r.all_done_s,
            r.failed,
            r.lost,
            r.dup_p99_ms,
            r.get_p99_ms,
            rate,
            p99
        );
    }
    let secured: Vec<_> = [false, true].into_iter().map(measure_with_token).collect();
    println!(
        "\n{:<42} {:>12} {:>11} {:>9}",
        "cached GET with a token", "GET p99", "wrk GET/s", "wrk p99"
    );
    for (mode, p99, wrk) in &secured {
        let (rate, wrk_p99) = wrk.as_ref().map_or(("-".to_string(), "-".to_string()), |(rate, p99)| {
            (format!("{rate:.0}"), p99.clone())
        });
        println!("{mode:<42} {p99:>9.2} ms {rate:>11} {wrk_p99:>9}");
    }
}
