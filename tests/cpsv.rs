//! `inside = "cpsv"` (cube maps from the empty space, voting) against the winding number:
//! agreement on closed shapes and meshes, an open-bottomed building, and its settings.

mod common;
use common::{concat, cuboid, defaults, torus};
use glam::Vec3;
use occluder_cook::mesh::{IngestLimits, Mesh, load_file, topology::orient_closed_components};
use occluder_cook::voxel::{Grid, InsideMethod, classify, cpsv::CpsvStats, surface};

/// (agreement of cpsv with winding over the voxels no triangle touches, cpsv's stats).
fn agreement(mut mesh: Mesh, resolution: usize) -> (f64, CpsvStats) {
    let topology = orient_closed_components(&mut mesh);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, resolution);
    let surface = surface(&mesh, &grid, None).unwrap();
    let cpsv = defaults().cook.cpsv();
    let run = |method| classify(method, &mesh, &topology, &grid, &surface, &cpsv, None).unwrap();
    let (c, w) = (run(InsideMethod::Cpsv), run(InsideMethod::Winding));
    let empty: Vec<usize> = (0..grid.len()).filter(|&i| !surface[i]).collect();
    let same = empty.iter().filter(|&&i| c.solid[i] == w.solid[i]).count();
    assert!(w.solid.iter().zip(&surface).any(|(&s, &t)| s && !t), "nothing inside");
    (same as f64 / empty.len() as f64, c.cpsv.expect("cpsv reports"))
}

#[test]
fn cpsv_agrees_with_winding_on_closed_shapes() {
    for (name, mesh) in [
        ("torus", torus(1.0, 0.4, 48, 24)),
        (
            "two overlapping cubes",
            concat(&[
                cuboid(Vec3::splat(-1.0), Vec3::splat(0.5), &[]),
                cuboid(Vec3::splat(-0.2), Vec3::splat(1.0), &[]),
            ]),
        ),
    ] {
        let (share, stats) = agreement(mesh, 32);
        eprintln!(
            "{name}: cpsv agrees with winding at {:.3}% of empty voxels; {stats:?}",
            share * 100.0
        );
        assert!(share >= 0.99, "{name}: {share}");
        assert!(stats.seeds > 0 && stats.seeds <= stats.cells);
    }
}

#[test]
fn an_open_bottomed_building_is_solid_inside_and_empty_around() {
    // No floor (face 2 is -y): crossing counts fail here; the article's cells outside the
    // bounds are outside but never seeds, and the seeds inside see walls and roof all around.
    let mut mesh = cuboid(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 1.5, 1.0), &[2]);
    let topology = orient_closed_components(&mut mesh);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 24);
    let surface = surface(&mesh, &grid, None).unwrap();
    let cpsv = defaults().cook.cpsv();
    let c = classify(InsideMethod::Cpsv, &mesh, &topology, &grid, &surface, &cpsv, None).unwrap();
    let at = |p: Vec3| c.solid[grid.containing(p.as_dvec3()).unwrap()];
    assert!(at(Vec3::new(0.0, 0.75, 0.0)), "the middle of the building");
    assert!(at(Vec3::new(0.5, 0.2, -0.5)), "near the open floor");
    // Around the building (the grid's padding), only voxels a wall touches are solid.
    let outside = (0..grid.len()).filter(|&i| {
        let [x, y, z] = grid.coords(i);
        let p = grid.center(x, y, z).as_vec3();
        p.cmplt(lo).any() || p.cmpgt(hi).any()
    });
    assert!(outside.into_iter().all(|i| !c.solid[i] || surface[i]));
    let inner = (0..grid.len()).filter(|&i| c.solid[i] && !surface[i]).count();
    let [x, y, z] = grid.dims.map(|d| d - 2);
    eprintln!("open building: {inner} inner voxels; {:?}", c.cpsv);
    assert!(inner as f64 > 0.6 * (x * y * z) as f64, "{inner} inner voxels");
}

#[test]
fn cpsv_agrees_with_winding_on_corpus_meshes() {
    let Some(dir) = common::corpus() else { return };
    // Each with its agreement when the floor was set, less a tenth of a point: open meshes leave
    // a few cells undecided.
    for (name, agreed) in [
        ("spot.obj", 1.0),
        ("cow.obj", 1.0),
        ("suzanne.obj", 1.0),
        ("teapot.obj", 0.99976),
        ("kenney-building-small-a.glb", 0.99004),
    ] {
        let (mesh, _) = load_file(&dir.join(name), &IngestLimits::default()).expect("corpus mesh loads");
        let (share, stats) = agreement(mesh, 64);
        eprintln!(
            "{name}: cpsv agrees with winding at {:.3}% of empty voxels; {stats:?}",
            share * 100.0
        );
        let floor = agreed - 0.001;
        assert!(share >= floor, "{name}: {share}");
    }
}

#[test]
fn cpsv_thresholds_are_checked_settings() {
    let set = |key: &str, value: i64| occluder_cook::config::load(None, &[(key.into(), toml::Value::Integer(value))]);
    assert_eq!(set("cook.cpsv_votes", 8).unwrap().cook.cpsv().votes, 8);
    let error = set("cook.cpsv_inside_faces", 7).unwrap_err().to_string();
    assert!(error.contains("cook.cpsv_inside_faces"), "{error}");
}
