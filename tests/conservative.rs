//! Occluders of synthetic shapes whose true inside is known: every vertex inside the solid, no
//! false pixels, and no box where no box fits.

mod common;
use common::{concat, cook_evaluated, cook_evaluated_with, cuboid, torus};
use glam::Vec3;
use occluder_cook::cook::cook;
use occluder_cook::occluder::Shape;

fn assert_vertices_inside(vertices: &[Vec3], inside: impl Fn(Vec3) -> bool) {
    for v in vertices {
        assert!(inside(*v), "occluder vertex {v} is outside the solid");
    }
}

fn in_box(p: Vec3, lo: Vec3, hi: Vec3) -> bool {
    let eps = 1e-5;
    p.cmpge(lo - eps).all() && p.cmple(hi + eps).all()
}

#[test]
fn building_without_floor() {
    let (lo, hi) = (Vec3::new(-1.0, 0.0, -1.5), Vec3::new(1.0, 2.0, 1.5));
    let cooked = cook_evaluated(cuboid(lo, hi, &[2]));
    let q = cooked.report.quality.unwrap();
    // At least its five faces, as surface pieces or a box.
    assert!(cooked.occluder.triangles() >= 10, "{:?}", cooked.report.notes);
    assert_vertices_inside(&cooked.occluder.mesh().positions, |p| in_box(p, lo, hi));
    assert_eq!(q.false_pixels_non_below, 0);
    assert!(q.coverage > 0.8, "coverage {}", q.coverage);
}

#[test]
fn two_overlapping_cubes() {
    let a = (Vec3::splat(-1.0), Vec3::splat(0.5));
    let b = (Vec3::splat(-0.5), Vec3::splat(1.0));
    let cooked = cook_evaluated(concat(&[cuboid(a.0, a.1, &[]), cuboid(b.0, b.1, &[])]));
    let q = cooked.report.quality.unwrap();
    assert_vertices_inside(&cooked.occluder.mesh().positions, |p| {
        in_box(p, a.0, a.1) || in_box(p, b.0, b.1)
    });
    assert_eq!(q.false_pixels, 0);
    assert_eq!(q.outside_samples, 0.0);
    assert!(q.coverage > 0.7, "coverage {}", q.coverage);
}

#[test]
fn cube_with_one_face_flipped() {
    let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
    let mut mesh = cuboid(lo, hi, &[]);
    mesh.triangles[2].swap(1, 2);
    mesh.triangles[3].swap(1, 2);
    let cooked = cook_evaluated(mesh);
    // Turned back, it is the closed cube again.
    let input = &cooked.report.input.topology;
    assert_eq!((input.reoriented_triangles, input.closed_components), (2, 1));
    let q = cooked.report.quality.unwrap();
    assert!(cooked.occluder.triangles() > 0);
    assert_vertices_inside(&cooked.occluder.mesh().positions, |p| in_box(p, lo, hi));
    assert_eq!(q.false_pixels, 0);
}

/// Double-sided art often copies each face wound the other way; the two windings cancel, which
/// left no inside and an occluder of surface pieces alone.
#[test]
fn a_torus_made_double_sided_cooks_as_the_torus() {
    let torus = torus(1.0, 0.45, 48, 24);
    let mut double_sided = torus.clone();
    double_sided
        .triangles
        .extend(torus.triangles.iter().map(|&[a, b, c]| [a, c, b]));
    let (single, double) = (cook_evaluated(torus.clone()), cook_evaluated(double_sided));
    let topology = &double.report.input.topology;
    assert_eq!(topology.duplicate_triangles, torus.triangles.len());
    assert_eq!(topology.closed_components, 1);
    assert!(double.report.boxes.kept > 0, "{:?}", double.report.notes);
    assert_eq!(double.occluder.mesh().positions, single.occluder.mesh().positions);
    assert_eq!(double.report.quality.unwrap().false_pixels, 0);
}

#[test]
fn torus_keeps_its_hole_open() {
    let (major, minor) = (1.0f32, 0.45f32);
    let cooked = cook_evaluated(torus(major, minor, 48, 24));
    let q = cooked.report.quality.unwrap();
    assert!(cooked.occluder.triangles() > 0);
    // Inside the tube: distance from the core circle below the minor radius.
    assert_vertices_inside(&cooked.occluder.mesh().positions, |p| {
        let ring = (p.x * p.x + p.z * p.z).sqrt() - major;
        (ring * ring + p.y * p.y).sqrt() <= minor + 1e-4
    });
    assert_eq!(q.false_pixels, 0);
    assert_eq!(q.outside_samples, 0.0);
}

/// 100 km out an f32 step is 0.008, which writing the occluder as f32 may move a corner by:
/// far more than the clearance from the surface that boxes and quads keep near the origin. 300
/// km out it is 0.03, most of a voxel, so even box faces left on the grid must keep clear.
#[test]
fn a_torus_far_from_the_origin_shows_no_false_pixel() {
    for offset in [Vec3::new(1e5, 0.0, -1e5), Vec3::splat(3e5)] {
        let mut far = torus(1.0, 0.45, 48, 24);
        for p in &mut far.positions {
            *p += offset;
        }
        for shapes in [[Shape::Boxes], [Shape::Quads]] {
            let cooked = cook_evaluated_with(far.clone(), &shapes);
            let q = cooked.report.quality.unwrap();
            assert!(cooked.occluder.triangles() > 0, "{offset} {shapes:?}");
            assert_eq!(q.false_pixels, 0, "{offset} {shapes:?}");
        }
    }
}

#[test]
fn wall_thinner_than_a_voxel_gives_no_box() {
    // 64 voxels over 4 units: a voxel is 0.0625 wide, the wall 0.03.
    let mut settings = common::defaults();
    settings.cook.shapes = vec![Shape::Boxes];
    let mesh = cuboid(Vec3::new(-2.0, 0.0, -0.015), Vec3::new(2.0, 3.0, 0.015), &[]);
    let cooked = cook(mesh, Default::default(), 0.0, &settings, false).expect("cooks");
    assert_eq!(cooked.occluder.triangles(), 0);
    assert_eq!(cooked.report.voxels.inner, 0);
    assert!(
        cooked.report.notes.iter().any(|n| n.contains("no inner voxels")),
        "{:?}",
        cooked.report.notes
    );
}

#[test]
fn a_stray_vertex_is_named_when_no_box_fits() {
    let mut mesh = torus(1.0, 0.45, 48, 24);
    mesh.positions[100] = Vec3::splat(-1e25);
    let cooked = cook(mesh, Default::default(), 0.0, &common::defaults(), false).expect("cooks");
    assert_eq!(cooked.report.voxels.inner, 0);
    assert!(
        cooked
            .report
            .notes
            .iter()
            .any(|n| n.contains("a vertex at (-1e25, -1e25, -1e25)")),
        "{:?}",
        cooked.report.notes
    );
}

#[test]
fn budget_and_key_are_respected() {
    let mesh = torus(1.0, 0.45, 48, 24);
    let cooked = cook_evaluated(mesh.clone());
    assert!(cooked.occluder.triangles() <= common::defaults().cook.max_triangles);
    // Same geometry, triangles in another order and rotated: same key.
    let mut shuffled = mesh.clone();
    shuffled.triangles.reverse();
    for t in &mut shuffled.triangles {
        t.rotate_left(1);
    }
    let again = cook_evaluated(shuffled);
    assert_eq!(cooked.report.key, again.report.key);
    let mut settings = common::defaults();
    settings.cook.resolution = 48;
    let other = cook(mesh, Default::default(), 0.0, &settings, false).expect("cooks");
    assert_ne!(cooked.report.key, other.report.key);
}
