//! The real binary as a server or worker process, and HTTP helpers, for the service tests.

use super::cuboid;
use glam::Vec3;
use occluder_cook::mesh::Mesh;
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A process of the real binary that prints a ready line first (`listening on ADDR` or
/// `worker ready`); killed when dropped.
pub struct Server {
    pub child: Child,
    /// `http://ADDR` for a server, empty for a worker.
    pub base: String,
}

impl Server {
    /// Starts `occluder-cook serve` on a free port over `data`, with `--set` overrides.
    pub fn start(data: &Path, sets: &[&str]) -> Server {
        Server::start_with_env(data, sets, &[])
    }

    /// [`Server::start`] with environment variables set for the server.
    pub fn start_with_env(data: &Path, sets: &[&str], env: &[(&str, &str)]) -> Server {
        let mut args = vec!["serve", "--listen", "127.0.0.1:0", "--data-dir", data.to_str().unwrap()];
        for s in sets {
            args.extend(["--set", s]);
        }
        Server::spawn(&args, env)
    }

    /// Runs the binary with `args` and waits for its ready line.
    pub fn spawn<S: AsRef<std::ffi::OsStr>>(args: &[S], env: &[(&str, &str)]) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
            .envs(env.iter().copied())
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("the binary starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let base = match line.trim() {
            "worker ready" => String::new(),
            ready => format!(
                "http://{}",
                ready
                    .strip_prefix("listening on ")
                    .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
            ),
        };
        Server { child, base }
    }

    pub fn kill_9(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// SIGTERM, and the exit status.
    pub fn terminate(mut self) -> std::process::ExitStatus {
        Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        self.child.wait().unwrap()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub struct Reply {
    pub status: u16,
    pub headers: ureq::http::HeaderMap,
    pub body: Vec<u8>,
}

impl Reply {
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|_| panic!("not JSON: {}", String::from_utf8_lossy(&self.body)))
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).and_then(|v| v.to_str().ok())
    }

    /// Asserts a JSON error body with this status and code.
    pub fn assert_error(&self, status: u16, code: &str) {
        assert_eq!(self.status, status, "{}", String::from_utf8_lossy(&self.body));
        assert_eq!(self.json()["error"]["code"], code);
        assert!(self.json()["error"]["message"].as_str().is_some_and(|m| !m.is_empty()));
    }
}

pub fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(60)))
        .build()
        .into()
}

pub fn reply(result: Result<ureq::http::Response<ureq::Body>, ureq::Error>) -> Reply {
    let mut response = result.expect("the server answers");
    Reply {
        status: response.status().as_u16(),
        headers: response.headers().clone(),
        body: response.body_mut().with_config().limit(u64::MAX).read_to_vec().unwrap(),
    }
}

pub fn get(url: &str, headers: &[(&str, &str)]) -> Reply {
    let mut request = agent().get(url);
    for (k, v) in headers {
        request = request.header(*k, *v);
    }
    reply(request.call())
}

pub fn post(url: &str, content_type: Option<&str>, body: &[u8]) -> Reply {
    let mut request = agent().post(url);
    if let Some(t) = content_type {
        request = request.header("Content-Type", t);
    }
    reply(request.send(body))
}

pub fn obj_text(mesh: &Mesh) -> Vec<u8> {
    let mut text = String::new();
    for p in &mesh.positions {
        text.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
    }
    for t in &mesh.triangles {
        text.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    text.into_bytes()
}

/// A small distinct mesh for each `i`.
pub fn small_mesh(i: usize) -> Vec<u8> {
    obj_text(&cuboid(Vec3::ZERO, Vec3::new(1.0 + i as f32 * 0.01, 1.0, 0.5), &[]))
}

pub fn data_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("occluder-cook-service-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Polls a job until it ends; returns its final JSON.
pub fn wait_for(base: &str, job: &str, limit: Duration) -> Value {
    let start = Instant::now();
    loop {
        assert!(start.elapsed() < limit, "job {job} not ended after {limit:?}");
        let status = get(&format!("{base}/v1/jobs/{job}"), &[]);
        // 503: the store is passing through a restart.
        if status.status != 503 {
            assert_eq!(status.status, 200, "{}", String::from_utf8_lossy(&status.body));
            let j = status.json();
            if j["state"] == "done" || j["state"] == "failed" {
                return j;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `GET /v1/jobs?limit=N` lists the N newest of `ids` (every job the store holds), newest first:
/// ids begin with their creation time, so the greatest.
pub fn assert_lists_newest(base: &str, ids: &[&str], limit: usize) {
    let mut expected = ids.to_vec();
    expected.sort_unstable_by(|a, b| b.cmp(a));
    expected.truncate(limit);
    let listed = get(&format!("{base}/v1/jobs?limit={limit}"), &[]).json();
    let listed: Vec<&str> = listed["jobs"]
        .as_array()
        .expect("a list of jobs")
        .iter()
        .map(|j| j["id"].as_str().expect("an id"))
        .collect();
    assert_eq!(listed, expected);
}
