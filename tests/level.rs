//! Levels from manifests: placement, batching, the shared cache, and clear errors for missing
//! meshes, bad transforms and empty levels.

mod common;
use common::cli;
use std::path::{Path, PathBuf};

fn workdir(name: &str) -> PathBuf {
    common::workdir(&format!("level-{name}"))
}

const BOX: &str = "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 2 1 0\nv 0 0 1\nv 2 0 1\nv 0 1 1\nv 2 1 1\n\
                   f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

fn translate(x: f64, z: f64) -> String {
    format!("[1,0,0,0, 0,1,0,0, 0,0,1,0, {x},0,{z},1]")
}

fn manifest(dir: &Path, instances: &[String]) -> PathBuf {
    let path = dir.join("level.json");
    std::fs::write(
        &path,
        format!("{{\"name\":\"test\",\"instances\":[{}]}}", instances.join(",")),
    )
    .unwrap();
    path
}

fn bake(dir: &Path, manifest: &Path) -> (i32, String, String) {
    bake_with(dir, manifest, &[])
}

/// [`bake`] with more arguments.
fn bake_with(dir: &Path, manifest: &Path, more: &[&str]) -> (i32, String, String) {
    let out = dir.join("level.glb");
    let report = dir.join("report.json");
    let data = dir.join("cache");
    let mut args = vec![
        "level",
        manifest.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--data-dir",
        data.to_str().unwrap(),
        "--set",
        "level.batch_max_extent=20",
    ];
    args.extend_from_slice(more);
    cli(&args)
}

#[test]
fn instances_share_one_cook_and_a_rebake_is_all_cached() {
    let dir = workdir("bake");
    std::fs::write(dir.join("box.obj"), BOX).unwrap();
    let instances: Vec<String> = (0..40)
        .map(|i| {
            format!(
                "{{\"mesh\":\"box.obj\",\"transform\":{}}}",
                translate((i % 8) as f64 * 5.0, (i / 8) as f64 * 5.0)
            )
        })
        .collect();
    let path = manifest(&dir, &instances);
    let (code, stdout, stderr) = bake(&dir, &path);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    println!("{stdout}");
    assert_eq!(
        (report["instances"].as_u64(), report["unique_meshes"].as_u64()),
        (Some(40), Some(1))
    );
    assert_eq!(report["cache_hits"], 0);
    // 40 boxes over 35 × 20 units, batches at most 20 wide: a few batches, one draw call each.
    let batches = report["batches"].as_u64().unwrap();
    assert!((2..=8).contains(&batches), "{batches} batches");
    assert_eq!(report["draw_calls_before"], 40);
    assert_eq!(report["draw_calls_after"], batches);
    let list: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("level.batches.json")).unwrap()).unwrap();
    let covered: usize = list
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["instances"].as_array().unwrap().len())
        .sum();
    assert_eq!(covered, 40);
    let glb = std::fs::read(dir.join("level.glb")).unwrap();
    assert_eq!(&glb[..4], b"glTF");
    // The bake's cull test: cameras among the boxes see some behind others, culled rightly.
    let cull = &report["cull"];
    assert_eq!(
        (cull["cameras"].as_u64(), cull["wrongly_culled"].as_u64()),
        (Some(8), Some(0)),
        "{cull}"
    );
    assert!(cull["culled_share"].as_f64().unwrap() > 0.0, "{cull}");
    assert!(stdout.contains("cull test: 8 cameras"), "{stdout}");
    let (code, _, stderr) = bake(&dir, &path);
    assert_eq!(code, 0, "{stderr}");
    let again: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(again["cache_hits"], 1, "the rebake is warm");
    assert_eq!(again["triangles_after"], report["triangles_after"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_manifests_are_one_line_errors() {
    let dir = workdir("errors");
    std::fs::write(dir.join("box.obj"), BOX).unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec![], "no instances"),
        (
            vec![format!(
                "{{\"mesh\":\"missing.obj\",\"transform\":{}}}",
                translate(0.0, 0.0)
            )],
            "`missing.obj` not found",
        ),
        (
            vec!["{\"mesh\":\"box.obj\",\"transform\":[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0]}".into()],
            "expected 16 numbers",
        ),
        (
            vec!["{\"mesh\":\"box.obj\",\"transform\":[1,0,0,0, 0,0,0,0, 0,0,1,0, 0,0,0,1]}".into()],
            "singular",
        ),
        // JSON has no NaN or infinity: such numbers fail the parse, with the place.
        (
            vec!["{\"mesh\":\"box.obj\",\"transform\":[1,0,0,0, 0,1,0,0, 0,0,1,0, 1e999,0,0,1]}".into()],
            "number out of range at line 1",
        ),
        (
            vec!["{\"mesh\":\"box.obj\",\"transform\":[1,0,0,0, 0,1,0,0, 0,0,1,0, NaN,0,0,1]}".into()],
            "expected value at line 1",
        ),
    ];
    for (instances, expected) in cases {
        let path = manifest(&dir, &instances);
        let (code, _, stderr) = bake(&dir, &path);
        assert_eq!(code, 1, "{stderr}");
        assert!(stderr.contains(expected), "expected {expected:?} in {stderr}");
        assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_obj_level_makes_each_group_an_instance() {
    let dir = workdir("groups");
    // OBJ indices count from the file's first vertex: the second box's faces refer to 9 to 16.
    let second: String = BOX
        .lines()
        .map(|l| match l.strip_prefix("f ") {
            Some(f) => {
                let shifted: Vec<String> = f
                    .split(' ')
                    .map(|i| (i.parse::<u32>().unwrap() + 8).to_string())
                    .collect();
                format!("f {}\n", shifted.join(" "))
            }
            None => format!(
                "{}\n",
                l.trim().replacen("v 0 ", "v 10 ", 1).replacen("v 2 ", "v 12 ", 1)
            ),
        })
        .collect();
    let two_groups = format!("g first\n{BOX}g second\n{second}");
    let path = dir.join("level.obj");
    std::fs::write(&path, two_groups).unwrap();
    let (code, stdout, stderr) = bake(&dir, &path);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("2 instances of 2 unique meshes (0 cached)"), "{stdout}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["triangles_before"], 24, "both boxes, each once");
    let batches: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("level.batches.json")).unwrap()).unwrap();
    let hi_x = batches
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["hi"][0].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert_eq!(hi_x, 12.0, "the second box stays where its group put it");
    let _ = std::fs::remove_dir_all(&dir);
}

/// cull-eval catches a wrong occluder, and passes the baked one.
#[test]
fn cull_eval_catches_an_occluder_that_hides_what_is_visible() {
    let dir = workdir("cull");
    std::fs::write(dir.join("box.obj"), BOX).unwrap();
    let instances: Vec<String> = (0..12)
        .map(|i| {
            format!(
                "{{\"mesh\":\"box.obj\",\"transform\":{}}}",
                translate((i % 4) as f64 * 6.0, (i / 4) as f64 * 6.0)
            )
        })
        .collect();
    let path = manifest(&dir, &instances);
    let (code, _, stderr) = bake(&dir, &path);
    assert_eq!(code, 0, "{stderr}");
    let level = path.to_str().unwrap();
    let baked = dir.join("level.glb");
    // The summary line, with the ground truth rendered on `device`; lavapipe's, where there
    // is no GPU, must give the same figures as the CPU's.
    let gpu = occluder_cook::gpu::best_adapter_info().is_some();
    let summary = |occluder: &std::path::Path, device: &str| {
        let (code, stdout, stderr) = cli(&[
            "cull-eval",
            level,
            occluder.to_str().unwrap(),
            "--cameras",
            "40",
            "--device",
            device,
        ]);
        assert_eq!(code, 0, "{stderr}");
        assert!(stdout.contains("ground truth on"), "{stdout}");
        stdout
            .lines()
            .find(|l| l.contains("cameras,"))
            .unwrap_or_default()
            .to_string()
    };
    let ours = summary(&baked, "cpu");
    assert!(ours.contains("wrongly culled 0"), "{ours}");
    if gpu {
        assert_eq!(summary(&baked, "gpu"), ours);
    }
    // A wall across the whole level hides boxes that are in plain sight.
    let wall = dir.join("wall.obj");
    std::fs::write(&wall, "v 9 -5 -50\nv 9 5 -50\nv 9 5 50\nv 9 -5 50\nf 1 2 3 4\n").unwrap();
    let wrong = summary(&wall, "cpu");
    assert!(
        !wrong.contains("wrongly culled 0"),
        "a wrong occluder must be caught: {wrong}"
    );
    if gpu {
        assert_eq!(summary(&wall, "gpu"), wrong);
    } else {
        eprintln!("no GPU adapter: the GPU ground truth is not compared");
    }

    // The preview sheet shows the wrongly culled in red, and the baked occluder's sheet none.
    let limits = occluder_cook::mesh::IngestLimits::default();
    let level = occluder_cook::level::load(&path, &limits).unwrap();
    let meshes = occluder_cook::level::cull::load_meshes(&level, &Default::default()).unwrap();
    let red_pixels = |occluder: &std::path::Path| {
        let (occluder, _) = occluder_cook::mesh::load_file(occluder, &limits).unwrap();
        let caption = occluder_cook::level::preview::LevelCaption {
            name: "cull".into(),
            instances: level.instances.len(),
            batches: 0,
            triangles: occluder.triangles.len(),
            cull: None,
        };
        let sheet = occluder_cook::level::preview::sheet(&level, &meshes, &occluder, &[], &caption).unwrap();
        sheet.save(dir.join("sheet.png")).unwrap();
        // Over the views only: the caption's legend has a red square of its own.
        let views = 2 * occluder_cook::eval::preview::VIEW_PIXELS as u32;
        sheet
            .enumerate_pixels()
            .filter(|(_, y, p)| *y < views && p[0] > 150 && p[1] < 100 && p[2] < 100)
            .count()
    };
    assert_eq!(red_pixels(&baked), 0);
    assert!(red_pixels(&wall) > 100, "the wall's wrongly culled boxes show in red");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A glTF scene whose one box mesh is placed by three nodes, one of them through a parent that
/// moves and mirrors it.
fn box_scene() -> String {
    use base64::Engine;
    let corners: Vec<f32> = (0..8)
        .flat_map(|i| [(i & 1) as f32 * 2.0, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
        .collect();
    let indices: Vec<u16> = occluder_cook::occluder::BOX_FACES
        .iter()
        .flat_map(|q| [q[0], q[1], q[2], q[0], q[2], q[3]].map(|i| i as u16))
        .collect();
    let mut buffer: Vec<u8> = corners.iter().flat_map(|v| v.to_le_bytes()).collect();
    buffer.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    let data = base64::engine::general_purpose::STANDARD.encode(&buffer);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1,2]}}],
        "nodes":[{{"mesh":0}},{{"mesh":0,"translation":[10,0,0]}},{{"translation":[0,0,10],"scale":[-1,1,1],"children":[3]}},{{"mesh":0}}],
        "meshes":[{{"name":"box","primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":{len},"uri":"data:application/octet-stream;base64,{data}"}}],
        "bufferViews":[{{"buffer":0,"byteLength":96}},{{"buffer":0,"byteOffset":96,"byteLength":72}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":8,"type":"VEC3","min":[0,0,0],"max":[2,1,1]}},
                     {{"bufferView":1,"componentType":5123,"count":36,"type":"SCALAR"}}]}}"#,
        len = buffer.len()
    )
}

#[test]
fn a_gltf_scene_makes_each_mesh_node_an_instance_of_one_unique_mesh() {
    let dir = workdir("scene");
    let path = dir.join("level.gltf");
    std::fs::write(&path, box_scene()).unwrap();
    let (code, stdout, stderr) = bake(&dir, &path);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("3 instances of 1 unique meshes (0 cached)"), "{stdout}");
    let batches: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("level.batches.json")).unwrap()).unwrap();
    let bound = |b: &serde_json::Value, side: &str, axis: usize| b[side][axis].as_f64().unwrap();
    let all = batches.as_array().unwrap();
    let lo_x = all.iter().map(|b| bound(b, "lo", 0)).fold(f64::MAX, f64::min);
    let hi_x = all.iter().map(|b| bound(b, "hi", 0)).fold(f64::MIN, f64::max);
    let hi_z = all.iter().map(|b| bound(b, "hi", 2)).fold(f64::MIN, f64::max);
    // The occluders lie inside the placed boxes: x from -2 (mirrored) to 12, z up to 11.
    assert!((-2.0..-1.5).contains(&lo_x), "the mirrored instance reaches x = {lo_x}");
    assert!(hi_x > 11.5 && hi_x <= 12.0, "the moved instance reaches x = {hi_x}");
    assert!(hi_z > 10.5 && hi_z <= 11.0, "the child instance reaches z = {hi_z}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn faces_between_touching_occluders_are_dropped() {
    let dir = workdir("touching");
    std::fs::write(dir.join("box.obj"), BOX).unwrap();
    // Three boxes 2 × 1 × 1: the second beside the first along x, the third on top of the first.
    let placed = [
        translate(0.0, 0.0),
        translate(2.0, 0.0),
        "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,1,0,1]".to_string(),
    ];
    let instances: Vec<String> = placed
        .iter()
        .map(|t| format!("{{\"mesh\":\"box.obj\",\"transform\":{t}}}"))
        .collect();
    let path = manifest(&dir, &instances);
    // Boxes, merged into a watertight solid: five faces of the box as double-sided surface pieces
    // would cover it too, and only solids' faces can be dropped.
    let (code, _, stderr) = bake_with(&dir, &path, &["--set", r#"cook.shapes=["boxes"]"#]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    // Two contacts, each a pair of faces of two triangles.
    assert_eq!(report["hidden_triangles_removed"], 8, "{report}");
    assert_eq!(report["triangles_after"], 36 - 8);
    let baked = dir.join("level.glb");
    let (code, stdout, stderr) = cli(&[
        "cull-eval",
        path.to_str().unwrap(),
        baked.to_str().unwrap(),
        "--cameras",
        "20",
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("wrongly culled 0"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}
