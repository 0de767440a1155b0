//! Tokens against the real binary: 401 without one, 403 with the wrong scope, the tokens file
//! read again without a restart, `submit --token`, no open service on a reachable address, each
//! token's quotas and its turn at the workers, and HTTPS with a certificate read again on change.

mod common;
use common::http::*;
use common::tls::certificate_authority;
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
    if method == "POST" {
        return post_mesh(url, token, &small_mesh(0));
    }
    let authorization = token.map(|t| format!("Bearer {t}"));
    let result = {
        let mut request = agent().get(url);
        if let Some(value) = &authorization {
            request = request.header("Authorization", value);
        }
        request.call()
    };
    reply(result)
}

/// A POST of an OBJ, with `token` as its bearer token if given.
fn post_mesh(url: &str, token: Option<&str>, obj: &[u8]) -> Reply {
    let mut request = agent().post(url).header("Content-Type", "model/obj");
    if let Some(token) = token {
        request = request.header("Authorization", &format!("Bearer {token}"));
    }
    reply(request.send(obj))
}

/// The job a submission was answered with.
fn job_of(reply: &Reply) -> String {
    assert!(
        matches!(reply.status, 200 | 202),
        "{}",
        String::from_utf8_lossy(&reply.body)
    );
    reply.json()["job"].as_str().unwrap().to_string()
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
        ("GET", "/v1/jobs", "read"),
        ("GET", "/v1/activity", "read"),
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

#[test]
fn one_tokens_hundred_jobs_do_not_hold_back_anothers_one() {
    let (dir, file) = folder_with_tokens_file("fair");
    let busy = new_token(&file, "busy", "read,cook");
    let calm = new_token(&file, "calm", "read,cook");
    let server = start_with_tokens(
        &dir,
        &file,
        &["service.workers=1", "service.token_submission_burst=1000"],
    );
    // Slow enough cooks that busy's jobs are still waiting when calm's arrives.
    let cook = format!("{}/v1/cook?resolution=128", server.base);
    let busy_jobs: Vec<String> = (0..100)
        .map(|i| job_of(&post_mesh(&cook, Some(&busy), &small_mesh(i))))
        .collect();
    let calm_job = job_of(&post_mesh(&cook, Some(&calm), &small_mesh(1000)));
    let job = |id: &str| with_token("GET", &format!("{}/v1/jobs/{id}", server.base), Some(&calm)).json();
    let started = Instant::now();
    let calm_done = loop {
        let state = job(&calm_job);
        if state["state"] == "done" {
            break state;
        }
        assert_ne!(state["state"], "failed", "{state}");
        assert!(started.elapsed() < Duration::from_secs(300), "{state}");
        std::thread::sleep(Duration::from_millis(20));
    };
    let tenth = job(&busy_jobs[9]);
    assert!(
        tenth["state"] != "done" || tenth["updated_ms"].as_u64() > calm_done["updated_ms"].as_u64(),
        "calm's one job finished at {} ms, after busy's tenth: {tenth}",
        calm_done["updated_ms"]
    );
    let done_before = busy_jobs.iter().filter(|id| job(id)["state"] == "done").count();
    println!("calm's job finished with {done_before} of busy's 100 done");
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_token_may_keep_only_so_many_jobs_queued() {
    let (dir, file) = folder_with_tokens_file("queued");
    let busy = new_token(&file, "busy", "cook");
    let calm = new_token(&file, "calm", "cook");
    let ops = new_token(&file, "ops", "admin");
    // An API node without workers: its jobs stay queued.
    let tokens_file = format!("service.tokens_file={}", file.display());
    let server = Server::spawn(
        &[
            "serve",
            "--no-workers",
            "--listen",
            "127.0.0.1:0",
            "--data-dir",
            dir.to_str().unwrap(),
            "--set",
            "service.auth=tokens",
            "--set",
            &tokens_file,
            "--set",
            "service.token_max_queued=3",
        ],
        &[],
    );
    let cook = format!("{}/v1/cook", server.base);
    for i in 0..3 {
        assert_eq!(post_mesh(&cook, Some(&busy), &small_mesh(i)).status, 202);
    }
    let refused = post_mesh(&cook, Some(&busy), &small_mesh(3));
    refused.assert_error(429, "queue_full");
    assert!(refused.header("retry-after").is_some());
    assert!(
        refused.json()["error"]["message"]
            .as_str()
            .unwrap()
            .contains("token_max_queued")
    );
    // A duplicate of a queued job joins it: it adds nothing to the queue.
    assert_eq!(post_mesh(&cook, Some(&busy), &small_mesh(0)).status, 202);
    assert_eq!(
        post_mesh(&cook, Some(&calm), &small_mesh(4)).status,
        202,
        "another token goes on"
    );
    let metrics = String::from_utf8(with_token("GET", &format!("{}/metrics", server.base), Some(&ops)).body).unwrap();
    assert!(
        metrics.contains("occluder_token_queued_jobs{token=\"busy\"} 3"),
        "{metrics}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn submit_over_https_trusts_the_ca_it_is_given_and_a_renewed_certificate_needs_no_restart() {
    let (dir, file) = folder_with_tokens_file("tls");
    let token = new_token(&file, "ci", "read,cook");
    let (ca, cert, key) = certificate_authority();
    let [ca_file, cert_file, key_file] = ["ca.pem", "cert.pem", "key.pem"].map(|name| dir.join(name));
    std::fs::write(&ca_file, &ca).unwrap();
    std::fs::write(&cert_file, &cert).unwrap();
    std::fs::write(&key_file, &key).unwrap();
    let server = start_with_tokens(
        &dir,
        &file,
        &[
            &format!("service.tls_cert={}", cert_file.display()),
            &format!("service.tls_key={}", key_file.display()),
        ],
    );
    let https = server.base.replace("http://", "https://");
    let mesh = dir.join("box.obj");
    std::fs::write(&mesh, small_mesh(0)).unwrap();
    let out = dir.join("out");
    let submit = |ca: &Path| {
        cli(&[
            "submit",
            mesh.to_str().unwrap(),
            "--server",
            &https,
            "--token",
            &token,
            "--ca-cert",
            ca.to_str().unwrap(),
            "--wait",
            "--out-dir",
            out.to_str().unwrap(),
        ])
    };
    let (code, stdout, stderr) = submit(&ca_file);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(out.join("box.occluder.glb").exists());
    // The public roots do not know this CA; plain HTTP gets no answer from a TLS port.
    let (code, _, stderr) = cli(&["fetch", "0", "--server", &https, "--token", &token, "-o", "x.glb"]);
    assert_eq!(code, 4, "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(agent().get(&format!("{}/healthz", server.base)).call().is_err());

    // A renewed certificate from another CA replaces the served one within moments.
    let (new_ca, new_cert, new_key) = certificate_authority();
    let new_ca_file = dir.join("new-ca.pem");
    std::fs::write(&new_ca_file, &new_ca).unwrap();
    std::fs::write(&key_file, &new_key).unwrap();
    std::fs::write(&cert_file, &new_cert).unwrap();
    let started = Instant::now();
    while submit(&new_ca_file).0 != 0 {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "the renewed certificate is not served"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    assert_eq!(submit(&ca_file).0, 4, "the old certificate is no longer served");
    assert!(server.terminate().success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn level_bakes_on_a_server_with_a_token() {
    let (dir, file) = folder_with_tokens_file("level");
    let token = new_token(&file, "artist", "read,cook");
    let server = start_with_tokens(&dir, &file, &[]);
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    std::fs::write(work.join("box.obj"), small_mesh(40)).unwrap();
    let manifest = work.join("level.json");
    std::fs::write(
        &manifest,
        r#"{"instances":[
            {"mesh":"box.obj","transform":[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]},
            {"mesh":"box.obj","transform":[1,0,0,0, 0,1,0,0, 0,0,1,0, 5,0,0,1]}]}"#,
    )
    .unwrap();
    let out = work.join("level.glb");
    let report = work.join("report.json");
    let level = |token: &str| {
        cli(&[
            "level",
            manifest.to_str().unwrap(),
            "--server",
            &server.base,
            "--token",
            token,
            "-o",
            out.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
            "--set",
            "cook.resolution=48",
        ])
    };
    let (code, stdout, stderr) = level("not-a-token");
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    let (code, stdout, stderr) = level(&token);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(stdout.contains("2 instances of 1 unique meshes"), "{stdout}");
    assert_eq!(&std::fs::read(&out).unwrap()[..4], b"glTF");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(report["instances"], 2);
    let batches: serde_json::Value =
        serde_json::from_slice(&std::fs::read(work.join("level.batches.json")).unwrap()).unwrap();
    assert_eq!(batches.as_array().map(Vec::len), Some(1), "{batches}");
    // `submit --level` sends the same upload: the same key, baked already.
    let out_dir = work.join("submitted");
    let (code, stdout, stderr) = cli(&[
        "submit",
        "--level",
        manifest.to_str().unwrap(),
        "--server",
        &server.base,
        "--token",
        &token,
        "-o",
        out_dir.to_str().unwrap(),
        "--set",
        "cook.resolution=48",
    ]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert_eq!(
        std::fs::read(out_dir.join("level.occluder.glb")).unwrap(),
        std::fs::read(&out).unwrap()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
