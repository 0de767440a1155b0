//! The binary as users run it: settings errors name the key, bad files exit non-zero with one
//! line, and cook → eval works on a mesh written here.

mod common;

use common::workdir;
use std::path::{Path, PathBuf};

fn run(args: &[&str]) -> (bool, String, String) {
    let (code, stdout, stderr) = common::cli(args);
    (code == 0, stdout, stderr)
}

fn write_cube_obj(dir: &Path) -> PathBuf {
    let path = dir.join("cube.obj");
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n\
         f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n",
    )
    .unwrap();
    path
}

#[test]
fn cook_then_eval() {
    let dir = workdir("cli-cook-eval");
    let input = write_cube_obj(&dir);
    let out = dir.join("cube.glb");
    let report = dir.join("cube.json");
    let (ok, stdout, stderr) = run(&[
        "cook",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--eval",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("false pixels 0"), "{stdout}");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    // The cube's own faces: five, double-sided, hide what it hides from every side.
    assert!(json["occluder"]["triangles"].as_u64().unwrap() <= 12, "{json}");
    assert_eq!(json["quality"]["false_pixels"], 0);
    let (ok, stdout, stderr) = run(&["eval", input.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("false pixels       0"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn errors_are_one_line_and_name_the_problem() {
    let dir = workdir("cli-errors");
    let input = write_cube_obj(&dir);
    let input = input.to_str().unwrap();
    let out = dir.join("x.glb");
    let out = out.to_str().unwrap();
    let bad_config = dir.join("bad.toml");
    std::fs::write(&bad_config, "[cook]\nresolutoin = 64\n").unwrap();
    let nan = dir.join("nan.obj");
    std::fs::write(&nan, "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n").unwrap();
    let far = dir.join("far.obj");
    std::fs::write(&far, "v 0 0 0\nv 1 0 0\nv 3e38 1 0\nf 1 2 3\n").unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["cook", input, "-o", out, "--set", "cook.colour=red"],
            "unknown setting `cook.colour`",
        ),
        (
            vec!["cook", input, "-o", out, "--resolution", "2"],
            "`cook.resolution` = 2 is out of range",
        ),
        (
            vec!["cook", input, "-o", out, "--set", "cook.max_boxes=many"],
            "`cook.max_boxes` must be integer",
        ),
        (
            vec!["cook", input, "-o", out, "--set", "cook.max_boxes=-3"],
            "`cook.max_boxes` = -3 is out of range",
        ),
        (
            vec!["cook", input, "-o", out, "--config", bad_config.to_str().unwrap()],
            "unknown setting `cook.resolutoin`",
        ),
        (
            vec!["cook", nan.to_str().unwrap(), "-o", out],
            "non-finite vertex coordinate",
        ),
        (
            vec!["cook", "/nonexistent/mesh.obj", "-o", out],
            "cannot read /nonexistent/mesh.obj",
        ),
        (vec!["cook", "mesh.dae", "-o", out], "unknown mesh format"),
        (vec!["cook", far.to_str().unwrap(), "-o", out], "lies past ±1e30"),
        (
            vec!["soak", "--worker-nodes", "2", "--duration", "1s"],
            "--worker-nodes needs --set service.nats_url",
        ),
        (
            vec!["soak", "--worker-nodes", "17", "--set", "service.nats_url=nats://x"],
            "--worker-nodes must be at most 16",
        ),
    ];
    for (args, expected) in cases {
        let (ok, _, stderr) = run(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bench_against_another_build_times_both_in_alternating_rounds() {
    let dir = workdir("cli-bench-against");
    let corpus = dir.join("corpus");
    std::fs::create_dir_all(&corpus).unwrap();
    write_cube_obj(&corpus);
    let json = dir.join("bench.json");
    let (corpus, json_path) = (corpus.to_str().unwrap(), json.to_str().unwrap());
    let itself = env!("CARGO_BIN_EXE_occluder-cook");
    let (ok, stdout, stderr) = run(&[
        "bench",
        "--corpus",
        corpus,
        "--json",
        json_path,
        "--device",
        "cpu",
        "--set",
        "cook.resolution=32",
        "--against",
        itself,
        "--rounds",
        "2",
    ]);
    assert!(ok, "{stderr}");
    let row: Vec<&str> = stdout
        .lines()
        .find(|l| l.starts_with("cube.obj"))
        .unwrap_or_else(|| panic!("no row for the cube: {stdout}"))
        .split_whitespace()
        .collect();
    // Median ms under each, their ratio and the median of the rounds' ratios; one build, so the
    // same coverage and triangles on both sides.
    assert!(
        row[1].parse::<f64>().unwrap() > 0.0 && row[2].parse::<f64>().unwrap() > 0.0,
        "{stdout}"
    );
    assert!(row[3].ends_with('x') && row[4].ends_with('x'), "{stdout}");
    assert_eq!((row[5], row[8]), (row[7], row[10]), "{stdout}");
    assert!(stdout.contains("1 meshes in both, medians of 2 rounds"), "{stdout}");
    for name in ["old.1", "old.2", "new.1", "new.2"] {
        let path = dir.join("bench.rounds").join(format!("{name}.json"));
        let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        // The settings reached both: a grid of 32 voxels along the longest side, and a border.
        let dims = &rows[0]["report"]["grid"]["dims"];
        let longest = (0..3).map(|k| dims[k].as_u64().unwrap()).max().unwrap();
        assert!((32..=34).contains(&longest), "{name}: {dims}");
    }
    let (ok, _, stderr) = run(&["bench", "--corpus", corpus, "--against", "/nonexistent/occluder-cook"]);
    assert!(!ok);
    assert!(stderr.contains("cannot run /nonexistent/occluder-cook"), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}
