//! The GLBs we write pass the Khronos glTF validator (npm `gltf-validator`, installed by .ci/run
//! into .ci/node_modules). Skips, saying so, where node or the validator is absent, except under
//! CI (`CI` set), where that fails.

use occluder_cook::mesh::{glb, shapes::torus};
use occluder_cook::occluder::{Panel, Shape, WorldBox, merge::merge, panel_mesh};
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

/// The validator's node modules, or None (saying so) where node or the validator is absent.
fn validator() -> Option<PathBuf> {
    let modules = Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/node_modules");
    if !modules.join("gltf-validator").is_dir() || Command::new("node").arg("--version").output().is_err() {
        // .ci/run installs both, so under CI their absence is a failure.
        assert!(
            std::env::var_os("CI").is_none(),
            "gltf-validator or node not found under CI: .ci/run installs them"
        );
        eprintln!("gltf-validator or node not found (run .ci/run to install it); skipping");
        return None;
    }
    Some(modules)
}

/// Fails unless the validator finds no error in the GLB at `path`.
fn assert_valid(modules: &Path, path: &Path) {
    let script = "const v = require('gltf-validator'); const fs = require('fs');\
        v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[1])))\
        .then(r => { console.log(JSON.stringify(r.issues)); process.exit(r.issues.numErrors ? 1 : 0); })\
        .catch(e => { console.error(e); process.exit(2); });";
    let out = Command::new("node")
        .env("NODE_PATH", modules)
        .args(["-e", script, path.to_str().unwrap()])
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&out.stdout);
    println!("{}: {report}", path.display());
    assert!(
        out.status.success(),
        "{}: {report} {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn occluder_glb_has_no_validator_errors() {
    let Some(modules) = validator() else { return };
    let occluder = merge(&[
        WorldBox {
            lo: [0.0; 3],
            hi: [2.0, 1.0, 1.0],
        },
        WorldBox {
            lo: [0.5, 1.0, 0.25],
            hi: [1.25, 1.6, 0.8],
        },
    ]);
    let dir = common::workdir("glb");
    let panels = panel_mesh(&[Panel {
        shape: Shape::Quads,
        corners: [[0.0, 0.5, 0.0], [2.0, 0.5, 0.0], [2.0, 0.5, 1.0], [0.0, 0.5, 1.0]],
    }]);
    for (name, mesh, panels) in [
        ("occluder.glb", occluder, panels),
        ("torus.glb", torus(1.0, 0.4, 16, 8), Default::default()),
        ("empty.glb", Default::default(), Default::default()),
    ] {
        let path = dir.join(name);
        let parts = [
            glb::Part {
                name: "solid",
                mesh: &mesh,
                double_sided: false,
            },
            glb::Part {
                name: "panels",
                mesh: &panels,
                double_sided: true,
            },
        ];
        std::fs::write(&path, glb::write(&parts, serde_json::json!({"key": "test"}))).unwrap();
        assert_valid(&modules, &path);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `convert` of every FBX and PLY file of the corpus writes a GLB the validator accepts.
#[test]
fn converted_fbx_and_ply_have_no_validator_errors() {
    let Some(modules) = validator() else { return };
    let Some(corpus) = common::corpus() else { return };
    let dir = common::workdir("convert");
    let mut converted = 0;
    for entry in std::fs::read_dir(corpus.join("formats")).unwrap() {
        let path = entry.unwrap().path();
        if !matches!(path.extension().and_then(|e| e.to_str()), Some("fbx" | "ply")) {
            continue;
        }
        let out = dir.join(path.file_name().unwrap()).with_extension("glb");
        let (code, stdout, stderr) = common::cli(&["convert", path.to_str().unwrap(), out.to_str().unwrap()]);
        assert_eq!(code, 0, "{}: {stderr}", path.display());
        print!("{stdout}");
        assert_valid(&modules, &out);
        converted += 1;
    }
    assert!(converted >= 6, "only {converted} FBX and PLY files");
    std::fs::remove_dir_all(&dir).unwrap();
}
