//! Tokens against the real binary: 401 without one, 403 with the wrong scope, the tokens file
//! read again without a restart, `submit --token`, and no open service on a reachable address.

mod common;
use common::http::*;
use common::{FBX_MIRRORED_CUBE, cli};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A new token from `token new`, appended to `file`.
fn new_token(file: &Path, name: &str, scopes: &str) -> String {
    let (code, stdout, stderr) = cli(&[
        "token",
        "new",
        "--name",
        name,
        "--scopes",
        scopes,
        "--file",
        file.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        !stderr.contains(stdout.trim()),
        "the token is shown once, on stdout only"
    );
    stdout.trim().to_string()
}

/// A fresh data folder and the tokens file in it.
fn folder_with_tokens_file(name: &str) -> (PathBuf, PathBuf) {
    let dir = data_dir(name);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("tokens.toml");
    (dir, file)
}

/// A server on `dir` that takes the tokens in `file`, with `sets` besides.
fn start_with_tokens(dir: &Path, file: &Path, sets: &[&str]) -> Server {
    let tokens_file = format!("service.tokens_file={}", file.display());
    let mut all = vec!["service.auth=tokens", tokens_file.as_str()];
    all.extend_from_slice(sets);
    Server::start(dir, &all)
}

/// A GET, or a POST of a small OBJ, with `token` as its bearer token if given.
fn with_token(method: &str, url: &str, token: Option<&str>) -> Reply {
    let authorization = token.map(|t| format!("Bearer {t}"));
    let result = if method == "POST" {
        let mut request = agent().post(url).header("Content-Type", "model/obj");
        if let Some(value) = &authorization {
            request = request.header("Authorization", value);
        }
        request.send(&small_mesh(0)[..])
    } else {
        let mut request = agent().get(url);
        if let Some(value) = &authorization {
            request = request.header("Authorization", value);
        }
        request.call()
    };
    reply(result)
}

#[test]
fn tokens_guard_every_endpoint_but_healthz_and_reload_without_a_restart() {
    let (dir, file) = folder_with_tokens_file("auth");
    let cook = new_token(&file, "ci", "read,cook");
    let reader = new_token(&file, "dashboard", "read");
    let server = start_with_tokens(&dir, &file, &[]);
    let base = &server.base;
    let endpoints = [
        ("POST", "/v1/cook", "cook"),
        ("POST", "/v1/levels", "cook"),
        ("GET", "/v1/jobs/j", "read"),
        ("GET", "/v1/jobs/j/events", "read"),
        ("GET", &format!("/v1/occluders/{}", "0".repeat(64)), "read"),
        ("GET", "/v1/occluders/k/report", "read"),
        ("GET", "/openapi.json", "read"),
        ("GET", "/metrics", "admin"),
        ("GET", "/v1/nowhere", "read"),
    ];
    for (method, path, scope) in &endpoints {
        let url = format!("{base}{path}");
        let refused = with_token(method, &url, None);
        refused.assert_error(401, "unauthorized");
        assert_eq!(refused.header("www-authenticate"), Some("Bearer"), "{path}");
        with_token(method, &url, Some("oct_forged")).assert_error(401, "unauthorized");
        let as_reader = with_token(method, &url, Some(&reader));
        match *scope {
            "read" => assert_ne!(as_reader.status, 401, "{path}"),
            _ => as_reader.assert_error(403, "forbidden"),
        }
    }
    assert_eq!(get(&format!("{base}/healthz"), &[]).status, 200);
    let accepted = with_token("POST", &format!("{base}/v1/cook"), Some(&cook));
    assert_eq!(accepted.status, 202, "{}", String::from_utf8_lossy(&accepted.body));
    // Only the token that filed a job, or an admin, may cancel it.
    let job_url = format!("{base}/v1/jobs/{}", accepted.json()["job"].as_str().unwrap());
    let cancel = |token: &str| {
        reply(
            agent()
                .delete(&job_url)
                .header("Authorization", &format!("Bearer {token}"))
                .call(),
        )
    };
    let other = new_token(&file, "other", "cook");
    let admin = new_token(&file, "ops", "admin");
    std::thread::sleep(Duration::from_millis(1100));
    cancel(&reader).assert_error(403, "forbidden");
    cancel(&other).assert_error(403, "forbidden");
    // Cancelled (200), or already done (409): either way let through.
    assert!(matches!(cancel(&admin).status, 200 | 409));
    assert!(matches!(cancel(&cook).status, 200 | 409));

    // A token added to the file works without a restart; one removed stops working.
    let late = new_token(&file, "late", "read");
    let works = |token: &str| {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            let status = with_token("GET", &format!("{base}/v1/jobs/j"), Some(token)).status;
            if status != 401 || Instant::now() > deadline {
                return status != 401;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    };
    assert!(works(&late), "a token added to the file is taken without a restart");
    let text = std::fs::read_to_string(&file).unwrap();
    let without_reader: Vec<&str> = text.split("\n[[token]]").filter(|t| !t.contains("dashboard")).collect();
    std::fs::write(&file, without_reader.join("\n[[token]]")).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while with_token("GET", &format!("{base}/v1/jobs/j"), Some(&reader)).status != 401 {
        assert!(Instant::now() < deadline, "a removed token still works");
        std::thread::sleep(Duration::from_millis(200));
    }

    // The CLI client: --token, and without it a refusal with the client's exit code 2.
    let fbx = dir.join("cube.fbx");
    std::fs::write(&fbx, FBX_MIRRORED_CUBE).unwrap();
    let (code, _, stderr) = cli(&[
        "submit",
        fbx.to_str().unwrap(),
        "--server",
        base,
        "--token",
        &cook,
        "--wait",
        "-o",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let (unknown, out) = ("0".repeat(64), dir.join("x.glb"));
    let (code, _, stderr) = cli(&["fetch", &unknown, "--server", base, "-o", out.to_str().unwrap()]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("unauthorized"), "{stderr}");
    assert!(server.terminate().success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn serve_refuses_a_reachable_address_without_auth() {
    let dir = data_dir("open");
    let (code, _, stderr) = cli(&["serve", "--listen", "0.0.0.0:0", "--data-dir", dir.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(stderr.contains("--insecure-no-auth"), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    let (code, _, stderr) = cli(&[
        "serve",
        "--data-dir",
        dir.to_str().unwrap(),
        "--set",
        "service.auth=tokens",
    ]);
    assert_eq!(code, 1);
    assert!(stderr.contains("service.tokens_file"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Each token has its own bucket of submissions: past it, 429 with Retry-After, and another
/// token still submits. Prometheus counts both per token name.
#[test]
fn each_token_submits_at_its_own_rate() {
    let (dir, file) = folder_with_tokens_file("rate");
    let busy = new_token(&file, "busy", "cook");
    let calm = new_token(&file, "calm", "cook");
    let ops = new_token(&file, "ops", "admin");
    let server = start_with_tokens(
        &dir,
        &file,
        &[
            "service.token_submission_burst=3",
            "service.token_submissions_per_s=0.01",
        ],
    );
    let cook = format!("{}/v1/cook", server.base);
    let statuses: Vec<u16> = (0..4).map(|_| with_token("POST", &cook, Some(&busy)).status).collect();
    assert!(statuses[..3].iter().all(|s| matches!(s, 200 | 202)), "{statuses:?}");
    let limited = with_token("POST", &cook, Some(&busy));
    limited.assert_error(429, "rate_limited");
    let wait: u64 = limited.header("retry-after").expect("Retry-After").parse().unwrap();
    assert!((1..=100).contains(&wait), "{wait}");
    assert_eq!(statuses[3], 429);
    assert_ne!(
        with_token("POST", &cook, Some(&calm)).status,
        429,
        "another token is not held back"
    );
    let metrics = String::from_utf8(with_token("GET", &format!("{}/metrics", server.base), Some(&ops)).body).unwrap();
    assert!(
        metrics.contains("occluder_submissions_limited_total{token=\"busy\"} 2"),
        "{metrics}"
    );
    assert!(server.terminate().success());
    let _ = std::fs::remove_dir_all(&dir);
}
