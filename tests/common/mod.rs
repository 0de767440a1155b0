//! Synthetic meshes whose true inside is known, and helpers shared by the tests.
#![allow(dead_code)]

pub mod http;
pub mod tls;

use glam::Vec3;
use occluder_cook::config::{self, Settings};
use occluder_cook::cook::{Cooked, cook};
use occluder_cook::mesh::{IngestStats, Mesh};
use occluder_cook::occluder::Shape;
use std::path::PathBuf;

/// An axis-aligned cube as 12 outward-facing triangles; `skip` names faces to leave out
/// (0: -x, 1: +x, 2: -y, 3: +y, 4: -z, 5: +z).
pub fn cuboid(lo: Vec3, hi: Vec3, skip: &[usize]) -> Mesh {
    let c = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let mut mesh = Mesh {
        positions: (0..8).map(c).collect(),
        triangles: Vec::new(),
    };
    for (f, q) in occluder_cook::occluder::BOX_FACES.iter().enumerate() {
        let q = q.map(|i| i as u32);
        if !skip.contains(&f) {
            mesh.triangles.push([q[0], q[1], q[2]]);
            mesh.triangles.push([q[0], q[2], q[3]]);
        }
    }
    mesh
}

/// A test's own folder under the system's temp folder, `occluder-cook-{name}-{pid}`, made empty:
/// tests run side by side, and one that rewrote another's files while they were read would fail
/// it. Each test removes its folder when it ends.
pub fn workdir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("occluder-cook-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The volume a closed mesh bounds: positive when its triangles face outwards.
pub fn signed_volume(mesh: &Mesh) -> f64 {
    (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

/// Several meshes as one, without welding.
pub fn concat(parts: &[Mesh]) -> Mesh {
    let mut out = Mesh::default();
    for p in parts {
        out.append(p);
    }
    out
}

#[allow(unused_imports)]
pub use occluder_cook::mesh::shapes::torus;

/// Solid voxels by winding or parity, which need neither the surface voxels nor cpsv's settings.
pub fn solid(
    method: occluder_cook::voxel::InsideMethod,
    mesh: &Mesh,
    topology: &occluder_cook::mesh::Topology,
    grid: &occluder_cook::voxel::Grid,
    gpu: Option<&occluder_cook::gpu::Gpu>,
) -> Vec<bool> {
    let cpsv = defaults().cook.cpsv();
    occluder_cook::voxel::classify(method, mesh, topology, grid, &[], &cpsv, gpu)
        .expect("classifies")
        .solid
}

pub fn defaults() -> Settings {
    config::load(None, &[]).expect("defaults load")
}

/// Cooks a synthetic mesh with evaluation at the default settings.
pub fn cook_evaluated(mesh: Mesh) -> Cooked {
    cook(mesh, IngestStats::default(), 0.0, &defaults(), true).expect("cooks")
}

/// The pieces the cook had before surface pieces: boxes, quads and patches.
pub const VOXEL_AND_PANEL_SHAPES: [Shape; 3] = [Shape::Boxes, Shape::Quads, Shape::Patches];

/// [`cook_evaluated`] with only the kinds of piece in `shapes`.
pub fn cook_evaluated_with(mesh: Mesh, shapes: &[Shape]) -> Cooked {
    let mut settings = defaults();
    settings.cook.shapes = shapes.to_vec();
    cook(mesh, IngestStats::default(), 0.0, &settings, true).expect("cooks")
}

/// The shared corpus of meshes, or None (with a message saying so) when it is absent; under CI
/// (`CI` set) its absence fails the test.
pub fn corpus() -> Option<PathBuf> {
    shared_dir("OCCLUDER_CORPUS", "meshes")
}

/// The shared levels, or None (with a message saying so) when they are absent.
pub fn levels() -> Option<PathBuf> {
    shared_dir("OCCLUDER_LEVELS", "levels")
}

fn shared_dir(variable: &str, folder: &str) -> Option<PathBuf> {
    let dir = std::env::var_os(variable)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared").join(folder));
    if dir.is_dir() {
        return Some(dir);
    }
    // CI has ../shared beside the clone: there a missing corpus is a failure, not a skip.
    assert!(
        std::env::var_os("CI").is_none(),
        "{folder} not found at {} under CI: the corpus tests must run there",
        dir.display()
    );
    eprintln!(
        "{folder} not found at {}: set {variable} to run the tests that need them; skipping",
        dir.display()
    );
    None
}

/// Runs the binary: (exit code, stdout, stderr).
pub fn cli(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
        .args(args)
        .output()
        .expect("the binary runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A 2 × 2 square on the plane y = 0 around the origin, facing up: two triangles.
pub fn square() -> Mesh {
    Mesh {
        positions: vec![
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(-1.0, 0.0, 1.0),
        ],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
    }
}

/// Runs `soak` for a minute with 3 clients and `args` besides, and checks what it reports: no job
/// lost, every accepted one ended, no cancel undone, no wrong bytes or keys, no answer off the
/// contract, and every kind of request sent. Returns the report.
pub fn soak_kept_its_promises(name: &str, args: &[&str]) -> serde_json::Value {
    let dir = std::env::temp_dir().join(format!("occluder-cook-soak-{name}-{}", std::process::id()));
    let json = dir.with_extension("json");
    let mut all = vec!["soak", "--duration", "60s", "--clients", "3", "--dir"];
    all.extend([dir.to_str().unwrap(), "--json", json.to_str().unwrap()]);
    all.extend(args);
    let (code, stdout, stderr) = cli(&all);
    println!("{stdout}");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert!(report["jobs_accepted"].as_u64() > Some(10), "{report}");
    assert_eq!(report["jobs_lost"], 0, "{report}");
    let ended: u64 = ["jobs_done", "jobs_failed", "jobs_cancelled"]
        .iter()
        .map(|field| report[field].as_u64().unwrap())
        .sum();
    assert_eq!(ended, report["jobs_accepted"].as_u64().unwrap(), "{report}");
    assert_eq!(report["cancels_undone"], 0, "{report}");
    assert_eq!(report["wrong_bytes"], 0, "{report}");
    assert_eq!(report["wrong_keys"], 0, "{report}");
    assert!(report["occluders_fetched"].as_u64() > Some(100), "{report}");
    assert_eq!(report["unexpected"], serde_json::json!({}), "{report}");
    for kind in [
        "new_mesh",
        "duplicate",
        "poll",
        "cancel",
        "cached_get",
        "malformed",
        "oversized",
        "unauthenticated",
    ] {
        assert!(
            report["requests"][kind].as_u64() > Some(0),
            "no {kind} requests: {report}"
        );
    }
    let minute = &report["minutes"][0];
    assert!(
        minute["cached_gets"].as_u64() > Some(0) && minute["peak_rss_mib"].as_f64() > Some(1.0),
        "{report}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&json);
    report
}

/// An ASCII FBX 7.4 cube in [0, 1]³, authored Z-up in metres, placed by a node mirrored in x and
/// moved 10 along x.
pub const FBX_MIRRORED_CUBE: &str = r#"; FBX 7.4.0 project file
FBXHeaderExtension:  {
	FBXHeaderVersion: 1003
	FBXVersion: 7400
}
GlobalSettings:  {
	Version: 1000
	Properties70:  {
		P: "UpAxis", "int", "Integer", "",2
		P: "UpAxisSign", "int", "Integer", "",1
		P: "FrontAxis", "int", "Integer", "",1
		P: "FrontAxisSign", "int", "Integer", "",-1
		P: "CoordAxis", "int", "Integer", "",0
		P: "CoordAxisSign", "int", "Integer", "",1
		P: "UnitScaleFactor", "double", "Number", "",100
	}
}
Objects:  {
	Geometry: 1, "Geometry::cube", "Mesh" {
		Vertices: *24 {
			a: 0,0,0,1,0,0,1,1,0,0,1,0,0,0,1,1,0,1,1,1,1,0,1,1
		}
		PolygonVertexIndex: *24 {
			a: 0,3,2,-2,4,5,6,-8,0,1,5,-5,1,2,6,-6,2,3,7,-7,3,0,4,-8
		}
	}
	Model: 2, "Model::cube", "Mesh" {
		Version: 232
		Properties70:  {
			P: "Lcl Translation", "Lcl Translation", "", "A",10,0,0
			P: "Lcl Scaling", "Lcl Scaling", "", "A",-1,1,1
		}
	}
}
Connections:  {
	C: "OO",2,0
	C: "OO",1,2
}
"#;
