//! The real server binary on a loopback port, driven over HTTP: submissions, deduplication, the
//! cache and its headers, every error status, a full queue, a kill -9 and restart, a corrupted
//! blob on disk, and a graceful SIGTERM.

mod common;
use common::http::*;
use common::{cli, cuboid, torus};
use glam::Vec3;
use occluder_cook::mesh::IngestLimits;
use occluder_cook::service::client::multipart;
use serde_json::Value;
use std::time::{Duration, Instant};

#[test]
fn submit_dedupe_cache_and_headers() {
    let dir = data_dir("basic");
    let server = Server::start(&dir, &[]);
    let base = &server.base;
    let cube = obj_text(&cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[]));

    let first = post(&format!("{base}/v1/cook"), Some("model/obj"), &cube);
    assert_eq!(first.status, 202, "{}", String::from_utf8_lossy(&first.body));
    let accepted = first.json();
    let (job, key) = (accepted["job"].as_str().unwrap(), accepted["key"].as_str().unwrap());
    assert_eq!(first.header("location"), Some(format!("/v1/jobs/{job}").as_str()));
    assert_eq!(accepted["result_url"], format!("/v1/occluders/{key}"));

    // The same mesh again, while queued or running or done: the same job, never a second one.
    let again = post(&format!("{base}/v1/cook?format=obj"), None, &cube);
    assert!(again.status == 202 || again.status == 200);
    assert_eq!(again.json()["job"], job);

    let events = get(&format!("{base}/v1/jobs/{job}/events"), &[]);
    let text = String::from_utf8_lossy(&events.body);
    assert!(text.contains("event: done"), "{text}");
    let done = wait_for(base, job, Duration::from_secs(60));
    assert_eq!(done["state"], "done");
    assert_eq!(done["progress"], 1.0);

    let glb = get(&format!("{base}/v1/occluders/{key}"), &[]);
    assert_eq!(glb.status, 200);
    assert_eq!(&glb.body[..4], b"glTF");
    assert_eq!(glb.header("etag"), Some(format!("\"{key}\"").as_str()));
    assert!(glb.header("cache-control").unwrap().contains("immutable"));
    assert_eq!(glb.header("content-type"), Some("model/gltf-binary"));
    let etag = format!("\"{key}\"");
    let not_modified = get(&format!("{base}/v1/occluders/{key}"), &[("If-None-Match", &etag)]);
    assert_eq!(not_modified.status, 304);
    let head = reply(agent().head(&format!("{base}/v1/occluders/{key}")).call());
    assert_eq!((head.status, head.body.len()), (200, 0));
    let report = get(&format!("{base}/v1/occluders/{key}/report"), &[]).json();
    assert_eq!(report["key"], key);
    // service.evaluate: the server judged it, and a cube's occluder hides nothing it should not.
    assert_eq!(report["quality"]["views"], 64, "{report}");
    assert_eq!(report["quality"]["false_pixels"], 0, "{report}");
    assert!(report["quality"]["coverage"].as_f64().unwrap() > 0.9, "{report}");

    // Cached: 200 and the job that made it. The same geometry as GLB has the same key.
    let cached = post(&format!("{base}/v1/cook"), Some("model/obj"), &cube);
    assert_eq!((cached.status, cached.json()["job"].as_str()), (200, Some(job)));
    let (mesh, _) =
        occluder_cook::mesh::load_bytes(&cube, occluder_cook::mesh::Format::Obj, None, &IngestLimits::default())
            .unwrap();
    let part = occluder_cook::mesh::glb::Part {
        name: "cube",
        mesh: &mesh,
        double_sided: false,
    };
    let as_glb = occluder_cook::mesh::glb::write(&[part], Value::Null);
    let from_glb = post(&format!("{base}/v1/cook"), Some("model/gltf-binary"), &as_glb);
    assert_eq!((from_glb.status, from_glb.json()["key"].as_str()), (200, Some(key)));
    // And as PLY, by its content type.
    let mut as_ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    for p in &mesh.positions {
        as_ply += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        as_ply += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    let from_ply = post(&format!("{base}/v1/cook"), Some("model/x-ply"), as_ply.as_bytes());
    assert_eq!((from_ply.status, from_ply.json()["key"].as_str()), (200, Some(key)));
    // FBX by ?format=.
    let fbx = post(
        &format!("{base}/v1/cook?format=fbx"),
        None,
        common::FBX_MIRRORED_CUBE.as_bytes(),
    );
    assert_eq!(fbx.status, 202, "{}", String::from_utf8_lossy(&fbx.body));
    // A changed setting is another key.
    let other = post(&format!("{base}/v1/cook?resolution=32"), Some("model/obj"), &cube);
    assert_eq!(other.status, 202);
    assert_ne!(other.json()["key"], key);
    // smallest_hole is part of the key once set; at 0 the key is the one without it.
    let hole = post(&format!("{base}/v1/cook?smallest_hole=0.5"), Some("model/obj"), &cube);
    assert_eq!(hole.status, 202);
    assert_ne!(hole.json()["key"], key);
    let zero = post(&format!("{base}/v1/cook?smallest_hole=0"), Some("model/obj"), &cube);
    assert_eq!((zero.status, zero.json()["key"].as_str()), (200, Some(key)));
    for accepted in [&fbx, &other, &hole] {
        wait_for(base, accepted.json()["job"].as_str().unwrap(), Duration::from_secs(60));
    }
    let (fbx_job, other_job) = (fbx.json()["job"].clone(), other.json()["job"].clone());
    let hole_job = hole.json()["job"].clone();
    let ids = [
        job,
        fbx_job.as_str().unwrap(),
        other_job.as_str().unwrap(),
        hole_job.as_str().unwrap(),
    ];
    for limit in [1, 2, 50] {
        assert_lists_newest(base, &ids, limit);
    }

    let unknown = "0".repeat(64);
    get(&format!("{base}/v1/occluders/{unknown}"), &[]).assert_error(404, "unknown_key");
    get(&format!("{base}/v1/occluders/nothex"), &[]).assert_error(400, "bad_key");
    get(&format!("{base}/v1/jobs/nope"), &[]).assert_error(404, "unknown_job");

    let health = get(&format!("{base}/healthz"), &[]);
    assert_eq!(health.json()["status"], "ok");
    let metrics = String::from_utf8(get(&format!("{base}/metrics"), &[]).body).unwrap();
    for name in [
        "occluder_cook_stage_seconds_bucket",
        "occluder_cache_hits_total",
        "occluder_cache_misses_total",
        "occluder_jobs{state=\"running\"}",
        "occluder_queue_depth",
        "occluder_cache_bytes",
        "occluder_workers 2",
    ] {
        assert!(metrics.contains(name), "{name} missing from /metrics:\n{metrics}");
    }
    // The dashboard's figures are the gauges', as JSON (once the last job's end has set them).
    let activity = get(&format!("{base}/v1/activity"), &[]).json();
    assert_eq!(
        (activity["workers"].as_u64(), activity["running"].as_u64()),
        (Some(2), Some(0))
    );
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let metrics = String::from_utf8(get(&format!("{base}/metrics"), &[]).body).unwrap();
        let gauge = |name: &str| {
            metrics
                .lines()
                .find_map(|l| l.strip_prefix(name)?.trim().parse::<f64>().ok())
        };
        let gauges = (gauge("occluder_cache_bytes "), gauge("occluder_queue_depth "));
        let shown = (activity["cache_bytes"].as_f64(), activity["queue_depth"].as_f64());
        if gauges == shown {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "/v1/activity {shown:?} vs /metrics {gauges:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let openapi = get(&format!("{base}/openapi.json"), &[]).json();
    for path in [
        "/v1/cook",
        "/v1/jobs/{id}",
        "/v1/jobs/{id}/events",
        "/v1/occluders/{key}",
    ] {
        assert!(openapi["paths"].get(path).is_some(), "{path} missing from openapi.json");
    }
    assert_eq!(openapi["components"]["securitySchemes"]["bearer"]["scheme"], "bearer");
    let uploads = &openapi["paths"]["/v1/cook"]["post"]["requestBody"]["content"];
    for media in [
        "model/gltf-binary",
        "model/vnd.fbx",
        "model/obj",
        "model/x-ply",
        "model/stl",
    ] {
        assert!(
            uploads.get(media).is_some(),
            "{media} missing from POST /v1/cook: {uploads}"
        );
    }
    assert!(server.terminate().success(), "SIGTERM ends the server cleanly");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_requests_get_json_errors_and_the_server_keeps_serving() {
    let dir = data_dir("errors");
    let server = Server::start(&dir, &["service.max_body_bytes=4096"]);
    let base = &server.base;
    let cook = format!("{base}/v1/cook");
    post(&cook, Some("model/obj"), &vec![b'#'; 10_000]).assert_error(413, "too_large");
    post(&cook, Some("model/obj"), b"this is not a mesh").assert_error(422, "bad_mesh");
    post(&cook, Some("model/obj"), b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n").assert_error(422, "bad_mesh");
    post(&cook, Some("model/obj"), b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n").assert_error(422, "bad_mesh");
    post(&cook, Some("model/gltf-binary"), b"glTF\x02\x00\x00\x00").assert_error(422, "bad_mesh");
    post(&cook, Some("model/obj"), b"").assert_error(422, "bad_mesh");
    post(&cook, None, &small_mesh(0)).assert_error(415, "unknown_format");
    post(&format!("{cook}?format=dae"), None, &small_mesh(0)).assert_error(400, "unknown_format");
    post(&format!("{cook}?format=ply"), None, &small_mesh(0)).assert_error(422, "bad_mesh");
    post(
        &format!("{cook}?max_placed_triangles=1"),
        Some("model/obj"),
        &small_mesh(0),
    )
    .assert_error(400, "bad_settings");
    post(&format!("{cook}?resolutoin=64"), Some("model/obj"), &small_mesh(0)).assert_error(400, "bad_settings");
    post(&format!("{cook}?resolution=-1"), Some("model/obj"), &small_mesh(0)).assert_error(400, "bad_settings");
    for width in ["-0.5", "nan", "inf", "wide"] {
        let url = format!("{cook}?smallest_hole={width}");
        post(&url, Some("model/obj"), &small_mesh(0)).assert_error(400, "bad_settings");
    }
    post(&format!("{cook}?resolution=1024"), Some("model/obj"), &small_mesh(0)).assert_error(422, "over_limit");
    // A glTF of a few hundred bytes that declares 2e9 positions no bytes back: refused unread.
    let sparse = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": 12, "uri": "data:application/octet-stream;base64,AAAAAAEAAAACAAAA"}],
        "bufferViews": [{"buffer": 0, "byteLength": 12}],
        "accessors": [
            {"componentType": 5126, "count": 2_000_000_000u64, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [0.0, 0.0, 0.0]},
            {"bufferView": 0, "componentType": 5125, "count": 3, "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    });
    post(&cook, Some("model/gltf+json"), sparse.to_string().as_bytes()).assert_error(413, "too_large");
    post(&format!("{cook}?quad_grid=4096"), Some("model/obj"), &small_mesh(0)).assert_error(422, "over_limit");
    post(&format!("{cook}?service.workers=9"), Some("model/obj"), &small_mesh(0)).assert_error(400, "bad_settings");
    get(&format!("{base}/v1/nowhere"), &[]).assert_error(404, "not_found");
    reply(agent().delete(&cook).call()).assert_error(405, "method_not_allowed");
    let ok = post(&cook, Some("model/obj"), &small_mesh(0));
    assert_eq!(ok.status, 202, "still serving after the bad requests");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_full_queue_answers_429_with_retry_after() {
    let dir = data_dir("queue");
    let server = Server::start(&dir, &["service.workers=1", "service.max_queue=1"]);
    let url = format!("{}/v1/cook?resolution=256", server.base);
    let statuses: Vec<Reply> = (0..4).map(|i| post(&url, Some("model/obj"), &small_mesh(i))).collect();
    let full = statuses
        .iter()
        .find(|r| r.status == 429)
        .expect("one submission finds the queue full");
    full.assert_error(429, "queue_full");
    assert_eq!(full.header("retry-after"), Some("5"));
    assert_eq!(statuses[0].status, 202);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The resolution of the jobs that must still run a second in: at most the servers'
/// `service.max_resolution`.
const SLOW: usize = 512;

/// A mesh whose cook at [`SLOW`] takes seconds on two cores: a torus with a hole, so that the
/// exposure stages and the open surface's winding numbers run too. A closed torus at 384 came
/// down to under a second.
fn slow_mesh() -> Vec<u8> {
    let mut mesh = torus(1.0, 0.45, 48, 24);
    mesh.triangles.drain(..6);
    obj_text(&mesh)
}

/// Posts [`slow_mesh`] to `base`'s cook endpoint at [`SLOW`]; the reply's JSON.
fn post_slow_cook(base: &str) -> Value {
    post(
        &format!("{base}/v1/cook?resolution={SLOW}"),
        Some("model/obj"),
        &slow_mesh(),
    )
    .json()
}

#[test]
fn kill_9_then_restart_loses_no_job_and_no_result() {
    let dir = data_dir("kill");
    let server = Server::start(&dir, &["service.workers=1", "service.max_resolution=512"]);
    let base = server.base.clone();
    let quick = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(1)).json();
    let quick_job = quick["job"].as_str().unwrap().to_string();
    wait_for(&base, &quick_job, Duration::from_secs(60));
    // A slow job and one queued behind it.
    let slow = post_slow_cook(&base);
    let behind = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(2)).json();
    let start = Instant::now();
    while get(&format!("{base}/v1/jobs/{}", slow["job"].as_str().unwrap()), &[]).json()["state"] != "running" {
        assert!(start.elapsed() < Duration::from_secs(30), "the slow job never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    server.kill_9();

    let server = Server::start(&dir, &["service.workers=1"]);
    let base = server.base.clone();
    for job in [&slow, &behind] {
        let done = wait_for(&base, job["job"].as_str().unwrap(), Duration::from_secs(180));
        assert_eq!(done["state"], "done", "{done}");
        let glb = get(&format!("{base}/v1/occluders/{}", job["key"].as_str().unwrap()), &[]);
        assert_eq!(glb.status, 200);
    }
    let slow_done = get(&format!("{base}/v1/jobs/{}", slow["job"].as_str().unwrap()), &[]).json();
    assert_eq!(slow_done["attempts"], 2, "the interrupted job ran again");
    let before = get(&format!("{base}/v1/occluders/{}", quick["key"].as_str().unwrap()), &[]);
    assert_eq!(before.status, 200, "a result finished before the kill is still there");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_corrupted_blob_is_never_served_and_is_cooked_again() {
    let dir = data_dir("corrupt");
    let server = Server::start(&dir, &[]);
    let base = server.base.clone();
    let accepted = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(3)).json();
    let key = accepted["key"].as_str().unwrap().to_string();
    wait_for(&base, accepted["job"].as_str().unwrap(), Duration::from_secs(60));
    let good = get(&format!("{base}/v1/occluders/{key}"), &[]).body;
    assert!(server.terminate().success());

    // Flip one byte of the stored GLB, behind the server's back.
    {
        let db = sled::open(&dir).unwrap();
        let glbs = db.open_tree("glbs").unwrap();
        let mut value = glbs.get(&key).unwrap().expect("the result is stored").to_vec();
        let last = value.len() - 1;
        value[last] ^= 0x55;
        glbs.insert(key.as_bytes(), value).unwrap();
        db.flush().unwrap();
    }

    let server = Server::start(&dir, &[]);
    let base = server.base.clone();
    let broken = get(&format!("{base}/v1/occluders/{key}"), &[]);
    broken.assert_error(404, "recomputing");
    let start = Instant::now();
    loop {
        let again = get(&format!("{base}/v1/occluders/{key}"), &[]);
        if again.status == 200 {
            assert_eq!(again.body, good, "the cooked-again result is the same");
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "never cooked again");
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The value of a gauge or counter in /metrics.
fn metric(base: &str, name: &str) -> f64 {
    let text = String::from_utf8(get(&format!("{base}/metrics"), &[]).body).unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.trim().parse().ok())
        .unwrap_or_else(|| panic!("{name} not in /metrics"))
}

#[test]
fn the_cache_evicts_the_least_recently_used_result() {
    let dir = data_dir("evict");
    let cook = |base: &str, i: usize| {
        let accepted = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(10 + i)).json();
        wait_for(base, accepted["job"].as_str().unwrap(), Duration::from_secs(60));
        accepted["key"].as_str().unwrap().to_string()
    };
    // Measure one result, then restart with room for two and a half of them.
    let server = Server::start(&dir, &["service.workers=1"]);
    let first = cook(&server.base, 0);
    let one = metric(&server.base, "occluder_cache_bytes");
    assert!(server.terminate().success());
    let limit = format!("service.max_cache_bytes={}", (one * 2.5) as u64);
    let server = Server::start(&dir, &["service.workers=1", &limit]);
    let base = server.base.clone();
    let second = cook(&base, 1);
    // Use the first again, so that the second is the least recently used.
    assert_eq!(get(&format!("{base}/v1/occluders/{first}"), &[]).status, 200);
    let third = cook(&base, 2);
    let status = |key: &str| get(&format!("{base}/v1/occluders/{key}"), &[]).status;
    assert_eq!((status(&first), status(&second), status(&third)), (200, 404, 200));
    assert_eq!(metric(&base, "occluder_evictions_total"), 1.0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn submit_and_fetch_from_the_cli_with_exit_codes_ci_can_trust() {
    let dir = data_dir("cli");
    let server = Server::start(&dir, &[]);
    let base = server.base.as_str();
    let work = data_dir("cli-work");
    std::fs::create_dir_all(&work).unwrap();
    let mesh = work.join("crate.obj");
    std::fs::write(&mesh, small_mesh(20)).unwrap();
    let mesh = mesh.to_str().unwrap();
    let out = work.join("out");
    let out_dir = out.to_str().unwrap();

    let (code, key_line, _) = cli(&["key", mesh]);
    assert_eq!(code, 0);
    let key = key_line.trim().to_string();
    let (code, stdout, stderr) = cli(&["submit", mesh, "--server", base, "--wait", "-o", out_dir]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains(&key), "the offline key is the server's key: {stdout}");
    let written = std::fs::read(out.join("crate.occluder.glb")).unwrap();
    assert_eq!(&written[..4], b"glTF");
    // Submitting again finds it by key with a HEAD, without uploading.
    let (code, _, stderr) = cli(&["submit", mesh, "--server", base, "--wait", "-o", out_dir]);
    assert_eq!(code, 0, "{stderr}");
    let fetched = work.join("fetched.glb");
    let (code, _, stderr) = cli(&["fetch", &key, "--server", base, "-o", fetched.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(std::fs::read(&fetched).unwrap(), written);

    let (code, _, stderr) = cli(&[
        "fetch",
        &"0".repeat(64),
        "--server",
        base,
        "-o",
        fetched.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "an unknown key is a rejection: {stderr}");
    let (code, _, stderr) = cli(&["submit", mesh, "--server", base, "--set", "cook.resolution=2"]);
    assert_eq!(code, 1, "bad settings fail locally first: {stderr}");
    let broken = work.join("broken.obj");
    std::fs::write(&broken, "v 0 0 0\nf 1 2 3\n").unwrap();
    let (code, _, stderr) = cli(&["submit", broken.to_str().unwrap(), "--server", base]);
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
    drop(server);
    let (code, _, stderr) = cli(&[
        "fetch",
        &key,
        "--server",
        "http://127.0.0.1:9",
        "-o",
        fetched.to_str().unwrap(),
    ]);
    assert_eq!(code, 4, "an unreachable server: {stderr}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&work);
}

/// One part of a multipart/form-data body: field name, file name, bytes.
type FormPart<'a> = (&'a str, &'a str, &'a [u8]);

fn level_manifest(placements: &[(&str, f64)]) -> Vec<u8> {
    let instances: Vec<String> = placements
        .iter()
        .map(|(mesh, x)| format!("{{\"mesh\":\"{mesh}\",\"transform\":[1,0,0,0, 0,1,0,0, 0,0,1,0, {x},0,0,1]}}"))
        .collect();
    format!("{{\"name\":\"api\",\"instances\":[{}]}}", instances.join(",")).into_bytes()
}

#[test]
fn a_level_is_baked_over_the_api_from_uploads_and_keys() {
    let dir = data_dir("levels");
    let server = Server::start(&dir, &[]);
    let base = &server.base;
    let levels = format!("{base}/v1/levels");
    // One mesh cooked before, named in the manifest by its key; another uploaded with it.
    let earlier = post(&format!("{base}/v1/cook?format=obj"), None, &small_mesh(7)).json();
    let known = earlier["key"].as_str().unwrap().to_string();
    let boxed = small_mesh(8);
    let manifest = level_manifest(&[("box.obj", 0.0), ("box.obj", 3.0), ("box.obj", 6.0), (&known, 9.0)]);
    let (content_type, body) = multipart(&[("manifest", "level.json", &manifest), ("mesh", "box.obj", &boxed)]);
    let queued = post(&levels, Some(&content_type), &body);
    assert_eq!(queued.status, 202, "{}", String::from_utf8_lossy(&queued.body));
    let key = queued.json()["key"].as_str().unwrap().to_string();
    let job = wait_for(base, queued.json()["job"].as_str().unwrap(), Duration::from_secs(120));
    assert_eq!(
        (job["state"].as_str(), job["kind"].as_str()),
        (Some("done"), Some("level")),
        "{job}"
    );
    let glb = get(&format!("{base}/v1/occluders/{key}"), &[]);
    assert_eq!(glb.status, 200);
    assert_eq!(&glb.body[..4], b"glTF");
    let report = get(&format!("{base}/v1/occluders/{key}/report"), &[]).json();
    assert_eq!(report["instances"], 4);
    assert_eq!(report["unique_meshes"], 2);
    let placed: usize = report["batches"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["instances"].as_array().unwrap().len())
        .sum();
    assert_eq!(placed, 4);
    // The same level again is the same key, already baked.
    let again = post(&levels, Some(&content_type), &body);
    assert_eq!((again.status, again.json()["key"].as_str()), (200, Some(key.as_str())));
    // The bake's own cull test: no instance culled while visible.
    assert_eq!(report["cull"]["cameras"], 8, "{report}");
    assert_eq!(report["cull"]["wrongly_culled"], 0, "{report}");
    // Preview sheets, a mesh's and the level's: drawn once from the kept inputs and the GLB,
    // then served as stored, immutable, with 304 for the ETag.
    for url in [
        format!("{base}/v1/occluders/{known}/preview.png"),
        format!("{base}/v1/levels/{key}/preview.png"),
    ] {
        let sheet = get(&url, &[]);
        assert_eq!(sheet.status, 200, "{url}: {}", String::from_utf8_lossy(&sheet.body));
        assert_eq!(sheet.header("content-type"), Some("image/png"));
        assert!(sheet.header("cache-control").is_some_and(|c| c.contains("immutable")));
        let image = image::load_from_memory(&sheet.body).unwrap();
        assert!(image.width() >= 640 && image.height() > image.width());
        assert_eq!(get(&url, &[]).body, sheet.body);
        let etag = sheet.header("etag").unwrap();
        let again = get(&url, &[("If-None-Match", etag)]);
        assert_eq!((again.status, again.body.len()), (304, 0), "{url}");
    }
    get(&format!("{base}/v1/occluders/{}/preview.png", "0".repeat(64)), &[]).assert_error(404, "no_preview");

    // Bad levels: JSON errors naming the problem, and the server keeps serving.
    let cube = obj_text(&cuboid(Vec3::ZERO, Vec3::ONE, &[]));
    let one = level_manifest(&[("c.obj", 0.0)]);
    let gone = level_manifest(&[("gone.obj", 0.0)]);
    let singular = br#"{"instances":[{"mesh":"c.obj","transform":[1,0,0,0, 0,0,0,0, 0,0,1,0, 0,0,0,1]}]}"#;
    // (parts, query, status, code, what the message says)
    let cases: Vec<(Vec<FormPart>, &str, u16, &str, &str)> = vec![
        (
            vec![("mesh", "c.obj", &cube)],
            "",
            400,
            "bad_multipart",
            "no `manifest` part",
        ),
        (
            vec![
                ("manifest", "m.json", &one),
                ("mesh", "c.obj", &cube),
                ("mesh", "d.obj", &cube),
            ],
            "",
            400,
            "bad_multipart",
            "part `d.obj` is not used",
        ),
        (
            vec![("manifest", "m.json", &gone)],
            "",
            422,
            "bad_level",
            "`gone.obj` not found",
        ),
        (
            vec![("manifest", "m.json", b"{\"instances\":")],
            "",
            422,
            "bad_level",
            "EOF",
        ),
        (
            vec![("manifest", "m.json", &singular[..]), ("mesh", "c.obj", &cube)],
            "",
            422,
            "bad_level",
            "singular",
        ),
        (
            vec![("manifest", "m.json", &one), ("mesh", "c.obj", b"v 0 0 nan\nf 1 1 1\n")],
            "",
            422,
            "bad_level",
            "part `c.obj`",
        ),
        (
            vec![("manifest", "m.json", &one), ("mesh", "c.obj", &cube)],
            "?service.workers=9",
            400,
            "bad_settings",
            "service.workers",
        ),
        (
            vec![("manifest", "m.json", &one), ("mesh", "c.obj", &cube)],
            "?level.bogus=1",
            400,
            "bad_settings",
            "level.bogus",
        ),
    ];
    for (parts, query, status, code, says) in cases {
        let (content_type, body) = multipart(&parts);
        let answer = post(&format!("{levels}{query}"), Some(&content_type), &body);
        answer.assert_error(status, code);
        let message = answer.json()["error"]["message"].as_str().unwrap().to_string();
        assert!(message.contains(says), "expected {says:?} in {message}");
    }
    post(&levels, Some("application/json"), &manifest).assert_error(400, "bad_multipart");
    assert_eq!(get(&format!("{base}/healthz"), &[]).status, 200);
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A job that asks for a GPU on a server without one is refused at once; `auto` still cooks.
#[test]
fn a_gpu_job_on_a_server_without_a_gpu_is_refused_up_front() {
    let dir = data_dir("no-gpu");
    let nowhere = "/nonexistent/icd.json";
    let server = Server::start_with_env(
        &dir,
        &[],
        &[("VK_ICD_FILENAMES", nowhere), ("VK_DRIVER_FILES", nowhere)],
    );
    let cook = format!("{}/v1/cook", server.base);
    post(&format!("{cook}?device=gpu"), Some("model/obj"), &small_mesh(0)).assert_error(422, "no_gpu");
    let ok = post(&format!("{cook}?device=auto"), Some("model/obj"), &small_mesh(0));
    assert_eq!(ok.status, 202, "{}", String::from_utf8_lossy(&ok.body));
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A job over service.job_timeout_s fails with `timeout`; DELETE cancels a queued job before it
/// starts and a running one at its next stage; the worker goes on with the next job.
#[test]
fn jobs_time_out_and_cancel_and_the_worker_goes_on() {
    let dir = data_dir("stop");
    let server = Server::start(
        &dir,
        &[
            "service.workers=1",
            "service.max_resolution=512",
            "service.job_timeout_s=1",
        ],
    );
    let base = &server.base;
    let slow = post_slow_cook(base);
    let timed_out = wait_for(base, slow["job"].as_str().unwrap(), Duration::from_secs(120));
    assert_eq!(timed_out["error"]["code"], "timeout", "{timed_out}");
    let quick = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(20)).json();
    assert_eq!(
        wait_for(base, quick["job"].as_str().unwrap(), Duration::from_secs(60))["state"],
        "done"
    );
    assert!(server.terminate().success());
    // The failed job's upload is gone from the store; the done one's stays, to remake its result.
    let inputs = tokio::runtime::Runtime::new().unwrap().block_on(async {
        use occluder_cook::store::Store;
        let store = occluder_cook::store::sled::SledStore::open(&dir, 1 << 24).unwrap();
        let kept = async |key: &Value| store.input(key.as_str().unwrap()).await.unwrap().is_some();
        (kept(&slow["key"]).await, kept(&quick["key"]).await)
    });
    assert_eq!(inputs, (false, true));

    let server = Server::start(&dir, &["service.workers=1", "service.max_resolution=512"]);
    let base = &server.base;
    let delete = |job: &str| reply(agent().delete(&format!("{base}/v1/jobs/{job}")).call());
    let running = post_slow_cook(base);
    let running = running["job"].as_str().unwrap().to_string();
    let queued = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(21)).json();
    let queued_key = queued["key"].clone();
    let queued = queued["job"].as_str().unwrap().to_string();
    let deadline = Instant::now() + Duration::from_secs(30);
    while get(&format!("{base}/v1/jobs/{running}"), &[]).json()["state"] != "running" {
        assert!(Instant::now() < deadline, "the slow job never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    let cancelled = delete(&queued);
    assert_eq!(cancelled.status, 200, "{}", String::from_utf8_lossy(&cancelled.body));
    assert_eq!(cancelled.json()["error"]["code"], "cancelled");
    let start = Instant::now();
    assert_eq!(delete(&running).status, 200);
    let stopped = wait_for(base, &running, Duration::from_secs(60));
    assert_eq!(
        (stopped["state"].as_str(), stopped["error"]["code"].as_str()),
        (Some("failed"), Some("cancelled"))
    );
    println!(
        "a running job stopped {:.2} s after its DELETE",
        start.elapsed().as_secs_f64()
    );
    assert_eq!(
        get(&format!("{base}/v1/jobs/{queued}"), &[]).json()["error"]["code"],
        "cancelled"
    );
    delete(&running).assert_error(409, "finished");
    delete(&"0".repeat(28)).assert_error(404, "unknown_job");
    let next = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(22)).json();
    assert_eq!(
        wait_for(base, next["job"].as_str().unwrap(), Duration::from_secs(60))["state"],
        "done"
    );
    // The cancelled mesh can be sent again: it is cooked anew.
    let again = post(&format!("{base}/v1/cook"), Some("model/obj"), &small_mesh(21));
    assert_eq!(again.status, 202, "{}", String::from_utf8_lossy(&again.body));
    wait_for(base, again.json()["job"].as_str().unwrap(), Duration::from_secs(60));
    assert!(server.terminate().success());
    // Cancelled while queued, its input went when the worker came to it; sent again, it is back.
    let kept = tokio::runtime::Runtime::new().unwrap().block_on(async {
        use occluder_cook::store::Store;
        let store = occluder_cook::store::sled::SledStore::open(&dir, 1 << 24).unwrap();
        store.input(queued_key.as_str().unwrap()).await.unwrap().is_some()
    });
    assert!(kept, "the second upload's input is kept");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A level over service.job_timeout_s fails with `timeout`; the meshes of a failed or refused
/// level leave no input behind; the results' bytes count their inputs; ended jobs' records go
/// after service.job_retention_s unless they made a stored result.
#[test]
fn failed_and_refused_work_leaves_nothing_behind_and_old_jobs_are_collected() {
    let dir = data_dir("collect");
    let server = Server::start(
        &dir,
        &[
            "service.workers=1",
            "service.max_resolution=512",
            "service.job_timeout_s=1",
            "service.job_retention_s=1",
        ],
    );
    let base = &server.base;
    let levels = format!("{base}/v1/levels");
    let slow_mesh = slow_mesh();
    let manifest = level_manifest(&[("t.obj", 0.0), ("t.obj", 4.0)]);
    let (content_type, body) = multipart(&[("manifest", "level.json", &manifest), ("mesh", "t.obj", &slow_mesh)]);
    let slow = post(&format!("{levels}?resolution={SLOW}"), Some(&content_type), &body).json();
    let level_job = slow["job"].as_str().unwrap().to_string();
    let failed = wait_for(base, &level_job, Duration::from_secs(120));
    assert_eq!(failed["error"]["code"], "timeout", "{failed}");
    let cube = small_mesh(31);
    let singular = br#"{"instances":[{"mesh":"c.obj","transform":[1,0,0,0, 0,0,0,0, 0,0,1,0, 0,0,0,1]}]}"#;
    let (content_type, body) = multipart(&[("manifest", "m.json", singular), ("mesh", "c.obj", &cube)]);
    post(&levels, Some(&content_type), &body).assert_error(422, "bad_level");
    let kept = small_mesh(30);
    let done = post(&format!("{base}/v1/cook"), Some("model/obj"), &kept).json();
    let done_job = done["job"].as_str().unwrap().to_string();
    assert_eq!(wait_for(base, &done_job, Duration::from_secs(60))["state"], "done");

    let started = Instant::now();
    while get(&format!("{base}/v1/jobs/{level_job}"), &[]).status != 404 {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "the failed level's record is never collected"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(
        get(&format!("{base}/v1/jobs/{done_job}"), &[]).json()["state"],
        "done",
        "it made a result"
    );
    let key = done["key"].as_str().unwrap();
    let glb = get(&format!("{base}/v1/occluders/{key}"), &[]).body.len();
    let report = get(&format!("{base}/v1/occluders/{key}/report"), &[]).body.len();
    let metrics = String::from_utf8(get(&format!("{base}/metrics"), &[]).body).unwrap();
    let input = 1 + "obj".len() + kept.len();
    assert!(
        metrics.contains(&format!("occluder_cache_bytes {}\n", glb + report + input)),
        "GLB {glb} + report {report} + input {input}: {metrics}"
    );
    assert!(server.terminate().success());
    // Only the done job's input is left in the store.
    let db = sled::open(&dir).unwrap();
    assert_eq!(db.open_tree("inputs").unwrap().len(), 1);
    drop(db);
    let _ = std::fs::remove_dir_all(&dir);
}
