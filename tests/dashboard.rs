//! The dashboard in a real browser: Debian's chromium, headless, driven through chromedriver
//! (WebDriver, with fantoccini) against the real server on loopback with tokens on. It enters
//! the token, uploads a mesh through the form, waits until the job page shows `done`, and checks
//! the preview image and the figures (triangles, coverage, false pixels) against the report. Screenshots at 1280×800 and at a
//! phone's 390×844 go to target/dashboard-*.png.
//!
//! Without chromium and chromedriver on PATH it says so and passes, except under CI (`CI=true`),
//! where .ci/run installs them and their absence is a failure.

mod common;
use common::http::*;
use common::{cli, cuboid};
use fantoccini::{ClientBuilder, Locator};
use glam::Vec3;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn installed(program: &str) -> bool {
    Command::new(program)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok()
}

/// Waits until `check` gives Some, polling; panics after `limit`.
async fn until<T, F, Fut>(what: &str, limit: Duration, mut check: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let started = Instant::now();
    loop {
        if let Some(value) = check().await {
            return value;
        }
        assert!(started.elapsed() < limit, "{what} after {limit:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The natural width of the job page's preview image, once it has loaded.
async fn preview_width(browser: &fantoccini::Client, what: &str) -> u64 {
    until(what, Duration::from_secs(60), || async {
        let width = browser
            .execute("return document.getElementById('preview').naturalWidth", vec![])
            .await
            .ok()?
            .as_u64()?;
        (width > 0).then_some(width)
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mesh_uploaded_through_the_dashboard_shows_its_preview_and_figures() {
    if !installed("chromium") || !installed("chromedriver") {
        assert!(
            std::env::var("CI").is_err(),
            "chromium or chromedriver is not installed: .ci/run installs the Debian packages chromium and chromium-driver"
        );
        eprintln!(
            "chromium or chromedriver not found (apt-get install chromium chromium-driver): skipping the browser test"
        );
        return;
    }
    let dir = data_dir("dashboard");
    std::fs::create_dir_all(&dir).unwrap();
    let tokens = dir.join("tokens.toml");
    let (code, token, stderr) = cli(&[
        "token",
        "new",
        "--name",
        "artist",
        "--scopes",
        "read,cook",
        "--file",
        tokens.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let token = token.trim().to_string();
    let server = Server::start(
        &dir,
        &[
            "service.auth=tokens",
            &format!("service.tokens_file={}", tokens.display()),
        ],
    );
    let mesh = dir.join("crate.obj");
    std::fs::write(&mesh, obj_text(&cuboid(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.5), &[]))).unwrap();

    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut driver = Command::new("chromedriver")
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let profile = dir.join("chromium-profile");
    let options = serde_json::json!({
        "binary": "/usr/bin/chromium",
        "args": [
            "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--window-size=1280,800", format!("--user-data-dir={}", profile.display()),
        ],
    });
    let mut capabilities = serde_json::Map::new();
    capabilities.insert("goog:chromeOptions".into(), options);
    let connector = hyper_util::client::legacy::connect::HttpConnector::new();
    let webdriver = format!("http://127.0.0.1:{port}");
    let browser = until("chromedriver does not answer", Duration::from_secs(30), || {
        let mut builder = ClientBuilder::new(connector.clone());
        builder.capabilities(capabilities.clone());
        let webdriver = webdriver.clone();
        async move { builder.connect(&webdriver).await.ok() }
    })
    .await;

    browser.goto(&format!("{}/", server.base)).await.unwrap();
    // The jobs list answers 401 without a token: the page asks for one.
    let form = until("no token form", Duration::from_secs(20), || async {
        let form = browser.find(Locator::Id("token-form")).await.ok()?;
        form.is_displayed().await.ok()?.then_some(form)
    })
    .await;
    form.find(Locator::Id("token"))
        .await
        .unwrap()
        .send_keys(&token)
        .await
        .unwrap();
    form.find(Locator::Css("button")).await.unwrap().click().await.unwrap();
    let file = browser.find(Locator::Id("file")).await.unwrap();
    file.send_keys(mesh.to_str().unwrap()).await.unwrap();
    browser
        .find(Locator::Id("submit"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();

    let state = until("the job page never shows done", Duration::from_secs(120), || async {
        let text = browser.find(Locator::Id("job-state")).await.ok()?.text().await.ok()?;
        assert_ne!(text, "failed");
        (text == "done").then_some(text)
    })
    .await;
    assert_eq!(state, "done");
    let width = preview_width(&browser, "the preview never loads").await;
    assert!(width >= 640, "{width}");
    // The figures shown are the report's.
    let shown = until("no figures", Duration::from_secs(30), || async {
        let text = browser.find(Locator::Id("job-figures")).await.ok()?.text().await.ok()?;
        text.contains("triangles out").then_some(text)
    })
    .await;
    let job = browser.find(Locator::Id("job-id")).await.unwrap().text().await.unwrap();
    let with_token = |path: &str| {
        let url = format!("{}{path}", server.base);
        reply(
            agent()
                .get(&url)
                .header("Authorization", &format!("Bearer {token}"))
                .call(),
        )
        .json()
    };
    let status = with_token(&format!("/v1/jobs/{job}"));
    let key = status["key"].as_str().unwrap();
    let report = with_token(&format!("/v1/occluders/{key}/report"));
    let out = report["occluder"]["triangles"].as_u64().unwrap();
    assert!(shown.contains(&format!("triangles out\n{out}")), "{shown} vs {out}");
    // The service judges every mesh: the coverage shown is the report's, to the digit shown.
    let coverage = report["quality"]["coverage"].as_f64().expect("the report has coverage");
    assert!(coverage > 0.9, "a crate's occluder covers it: {coverage}");
    let coverage = format!("coverage\n{:.1}%", coverage * 100.0);
    assert!(shown.contains(&coverage), "{shown} vs {coverage}");
    assert!(shown.contains("false pixels\n0"), "{shown}");
    let rows = browser.find_all(Locator::Css("#jobs tbody tr")).await.unwrap();
    assert_eq!(rows.len(), 1, "the jobs list shows the one job");

    let target = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    let desktop = browser.screenshot().await.unwrap();
    std::fs::write(target.join("dashboard-1280x800.png"), &desktop).unwrap();
    browser.set_window_size(390, 844).await.unwrap();
    let phone = browser.screenshot().await.unwrap();
    std::fs::write(target.join("dashboard-phone.png"), &phone).unwrap();

    // A level posted over the API: its page shows the batches and the bake's cull figures.
    let manifest = br#"{"name":"yard","instances":[
        {"mesh":"crate.obj","transform":[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]},
        {"mesh":"crate.obj","transform":[1,0,0,0, 0,1,0,0, 0,0,1,0, 4,0,0,1]},
        {"mesh":"crate.obj","transform":[1,0,0,0, 0,1,0,0, 0,0,1,0, 8,0,0,1]}]}"#;
    let crate_obj = std::fs::read(&mesh).unwrap();
    let (content_type, body) = occluder_cook::service::client::multipart(&[
        ("manifest", "yard.json", manifest),
        ("mesh", "crate.obj", &crate_obj),
    ]);
    let queued = reply(
        agent()
            .post(&format!("{}/v1/levels", server.base))
            .header("Authorization", &format!("Bearer {token}"))
            .header("Content-Type", &content_type)
            .send(&body[..]),
    );
    assert_eq!(queued.status, 202, "{}", String::from_utf8_lossy(&queued.body));
    let level_job = queued.json()["job"].as_str().unwrap().to_string();
    browser.set_window_size(1280, 800).await.unwrap();
    browser.goto(&format!("{}/#{level_job}", server.base)).await.unwrap();
    browser.refresh().await.unwrap();
    let shown = until(
        "the level's page never shows its figures",
        Duration::from_secs(120),
        || async {
            let text = browser.find(Locator::Id("job-figures")).await.ok()?.text().await.ok()?;
            text.contains("wrongly culled").then_some(text)
        },
    )
    .await;
    let level_key = with_token(&format!("/v1/jobs/{level_job}"))["key"]
        .as_str()
        .unwrap()
        .to_string();
    let level = with_token(&format!("/v1/occluders/{level_key}/report"));
    assert!(shown.contains("wrongly culled\n0"), "{shown}");
    let cameras = level["cull"]["cameras"].as_u64().unwrap();
    let culled = format!(
        "{:.1}% in view ({cameras} cameras)",
        level["cull"]["culled_share"].as_f64().unwrap() * 100.0
    );
    assert!(shown.contains(&culled), "{shown} vs {culled}");
    for batch in level["batches"].as_array().unwrap() {
        let line = format!("{}\n{} triangles", batch["name"].as_str().unwrap(), batch["triangles"]);
        assert!(shown.contains(&line), "{shown} vs {line}");
    }
    assert!(preview_width(&browser, "the level's preview never loads").await >= 640);
    std::fs::write(target.join("dashboard-level.png"), browser.screenshot().await.unwrap()).unwrap();
    println!("screenshots: {}", target.join("dashboard-*.png").display());
    browser.close().await.unwrap();
    let _ = driver.kill();
    let _ = driver.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
