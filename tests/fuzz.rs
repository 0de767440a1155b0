//! A short fuzzing run over seeds built here, one per format and encoding: no panic, no slow
//! input, and the mutations both read and refuse.

mod common;
use common::cuboid;
use glam::Vec3;
use occluder_cook::fuzz::{FuzzSettings, Seed, run};
use occluder_cook::mesh::{Format, IngestLimits, glb};

fn seeds() -> Vec<Seed> {
    let cube = cuboid(Vec3::ZERO, Vec3::ONE, &[]);
    let mut obj = String::new();
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        cube.positions.len(),
        cube.triangles.len()
    );
    let mut stl = vec![0u8; 80];
    stl.extend((cube.triangles.len() as u32).to_le_bytes());
    for p in &cube.positions {
        obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
        ply += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    for (t, tri) in cube.triangles.iter().enumerate() {
        obj += &format!("f {} {} {}\n", tri[0] + 1, tri[1] + 1, tri[2] + 1);
        ply += &format!("3 {} {} {}\n", tri[0], tri[1], tri[2]);
        stl.extend([0u8; 12]);
        for p in cube.corners(t) {
            stl.extend(p.to_array().iter().flat_map(|c| c.to_le_bytes()));
        }
        stl.extend([0, 0]);
    }
    let part = glb::Part {
        name: "cube",
        mesh: &cube,
        double_sided: false,
    };
    let glb = glb::write(&[part], serde_json::json!({}));
    [
        ("cube.obj", Format::Obj, obj.into_bytes()),
        ("cube.ply", Format::Ply, ply.into_bytes()),
        ("cube.stl", Format::Stl, stl),
        ("cube.glb", Format::Gltf, glb),
        ("cube.fbx", Format::Fbx, common::FBX_MIRRORED_CUBE.as_bytes().to_vec()),
    ]
    .into_iter()
    .map(|(name, format, bytes)| Seed {
        name: name.into(),
        format,
        bytes,
    })
    .collect()
}

#[test]
fn a_short_fuzzing_run_finds_no_panic_and_no_slow_input() {
    let settings = FuzzSettings {
        inputs: 5000,
        seed: 7,
        max_ms: 2000.0,
        limits: IngestLimits::default(),
    };
    let report = run(&seeds(), &settings, &|_| {});
    println!("{report:?}");
    assert_eq!(report.inputs, 5000);
    assert_eq!(report.per_format.len(), 5, "{:?}", report.per_format);
    assert!(report.accepted > 0 && report.rejected > 0, "{report:?}");
    assert!(report.findings.is_empty(), "{:?}", report.findings);
}
