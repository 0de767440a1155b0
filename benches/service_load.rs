//! Load on the real server binary over loopback (run with `cargo bench --bench service_load`):
//!
//! 1. 200 distinct small cook jobs submitted at once from 64 connections: time until all are
//!    done, errors, lost jobs;
//! 2. a duplicate submission of a cached mesh, 1,000 times over 64 connections: latency;
//! 3. cached `GET /v1/occluders/{key}`, 1,000 times over 64 connections: latency and rate; and,
//!    where `wrk` is installed, 10 s of it with 64 connections for the sustained rate.
//!
//! The load generator runs on the same machine as the server, as a studio's CI box would.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const CONNECTIONS: usize = 64;

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(300)))
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
    let next = AtomicUsize::new(0);
    let errors = AtomicUsize::new(0);
    let latencies = Mutex::new(Vec::with_capacity(count));
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..CONNECTIONS {
            s.spawn(|| {
                let agent = agent();
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

fn main() {
    let data = std::env::temp_dir().join(format!("occluder-cook-load-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data);
    let mut server = Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .args(["--set", "service.max_queue=1000"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("the server starts");
    let mut line = String::new();
    BufReader::new(server.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let base = format!("http://{}", line.trim().trim_start_matches("listening on "));
    println!("server at {base}, {CONNECTIONS} connections");

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
    println!(
        "200 jobs: {done} done, {failed} failed, {} lost, all finished {:.2} s after submission ({:.1} jobs/s)",
        200 - done - failed,
        all_done.as_secs_f64(),
        200.0 / all_done.as_secs_f64()
    );

    // 2. Duplicate submissions of a cached mesh.
    let cached = mesh(0);
    let (latencies, errors, wall) = hammer(1000, |agent, _| {
        let reply = agent
            .post(&format!("{base}/v1/cook"))
            .header("Content-Type", "model/obj")
            .send(&cached[..]);
        ok_200(reply)
    });
    report("duplicate submission of a cached mesh", latencies, errors, wall);

    // 3. Cached GETs.
    let mut r = agent
        .post(&format!("{base}/v1/cook"))
        .header("Content-Type", "model/obj")
        .send(&cached[..])
        .unwrap();
    let body: serde_json::Value = serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
    let url = format!("{base}{}", body["result_url"].as_str().unwrap());
    let (latencies, errors, wall) = hammer(1000, |agent, _| ok_200(agent.get(&url).call()));
    report("cached GET /v1/occluders/{key}", latencies, errors, wall);
    // wrk drives far more load than these threads can: the server's own rate and latency.
    let script = data.join("post.lua");
    let body = String::from_utf8(cached.clone()).unwrap();
    std::fs::write(
        &script,
        format!("wrk.method = \"POST\"\nwrk.headers[\"Content-Type\"] = \"model/obj\"\nwrk.body = {body:?}\n"),
    )
    .unwrap();
    let wrk = |what: &str, args: &[&str]| match Command::new("wrk")
        .args(["-t2", &format!("-c{CONNECTIONS}"), "-d10s", "--latency"])
        .args(args)
        .output()
    {
        Ok(out) => println!("wrk, {what}:\n{}", String::from_utf8_lossy(&out.stdout)),
        Err(_) => println!("wrk not installed (apt-get install wrk): {what} not measured"),
    };
    wrk("cached GET /v1/occluders/{key}", &[&url]);
    wrk(
        "duplicate POST /v1/cook of a cached mesh",
        &["-s", script.to_str().unwrap(), &format!("{base}/v1/cook")],
    );
    let _ = Command::new("kill").args(["-TERM", &server.id().to_string()]).status();
    let _ = server.wait();
    let _ = std::fs::remove_dir_all(&data);
}
