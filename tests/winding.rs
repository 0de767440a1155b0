//! The fast winding number (column crossings plus the boundary curtain) against its definition.

mod common;
use common::{cuboid, torus};
use glam::{DVec3, Vec3};
use occluder_cook::mesh::topology::orient_closed_components;
use occluder_cook::voxel::winding::{WindingField, direct};

fn probe_points() -> Vec<DVec3> {
    let mut rng = fastrand::Rng::with_seed(7);
    (0..400)
        .map(|_| DVec3::new(rng.f64() * 3.0 - 1.5, rng.f64() * 3.0 - 1.5, rng.f64() * 3.0 - 1.5))
        .collect()
}

fn assert_matches_definition(mut mesh: occluder_cook::mesh::Mesh) {
    let topology = orient_closed_components(&mut mesh);
    let field = WindingField::new(&mesh, &topology.boundary);
    let mut worst = 0.0f64;
    for p in probe_points() {
        worst = worst.max((field.winding(p) - direct(&mesh, p)).abs());
    }
    assert!(worst < 1e-6, "largest difference {worst}");
}

#[test]
fn closed_cube_matches_definition() {
    assert_matches_definition(cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[]));
}

#[test]
fn open_box_matches_definition() {
    assert_matches_definition(cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[2]));
    assert_matches_definition(cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[0, 3, 5]));
}

#[test]
fn flipped_face_matches_definition() {
    let mut mesh = cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[]);
    mesh.triangles[4].swap(1, 2);
    mesh.triangles[5].swap(1, 2);
    assert_matches_definition(mesh);
}

#[test]
fn torus_matches_definition() {
    assert_matches_definition(torus(1.0, 0.4, 24, 12));
}

#[test]
fn inverted_closed_part_counts_as_solid() {
    let mut mesh = cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[]);
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
    let topology = orient_closed_components(&mut mesh);
    assert_eq!(topology.inverted_components, 1);
    let field = WindingField::new(&mesh, &topology.boundary);
    assert!((field.winding(DVec3::ZERO) - 1.0).abs() < 1e-9);
}
