//! Thin and flat geometry: quads inside walls thinner than a voxel, patches on single-sided
//! planes, and openings that stay open. Surface pieces are left out: they would be these meshes
//! themselves (tests/surface_pieces.rs).

mod common;
use common::{VOXEL_AND_PANEL_SHAPES, concat, cook_evaluated_with, cuboid};
use glam::{DVec3, Vec3};
use occluder_cook::cook::Cooked;
use occluder_cook::geom::camera::View;
use occluder_cook::geom::raster::coverage_mask;
use occluder_cook::occluder::{Panel, Shape};

fn of_shape(cooked: &Cooked, shape: Shape) -> Vec<Panel> {
    cooked
        .occluder
        .panels
        .iter()
        .copied()
        .filter(|p| p.shape == shape)
        .collect()
}

fn assert_conservative(cooked: &Cooked) {
    let q = cooked.report.quality.as_ref().expect("evaluated");
    assert_eq!(q.false_pixels, 0, "{q:?}");
    assert_eq!(q.outside_samples, 0.0, "{q:?}");
}

#[test]
fn slab_a_tenth_of_a_voxel_thick_gives_one_quad_inside_it() {
    // 64 voxels over 4 units: a voxel is 0.0625, the slab 0.00625.
    let half = 0.003125;
    let cooked = cook_evaluated_with(
        cuboid(Vec3::new(-2.0, 0.0, -half), Vec3::new(2.0, 3.0, half), &[]),
        &VOXEL_AND_PANEL_SHAPES,
    );
    let half = f64::from(half);
    let quads = of_shape(&cooked, Shape::Quads);
    assert_eq!(quads.len(), 1, "{:?}", cooked.occluder.panels);
    assert_eq!(cooked.report.occluder.boxes, 0);
    for c in quads[0].corners {
        assert!(c[2].abs() < half, "corner {c:?} is not inside the slab");
    }
    // Nearly the whole slab, seen face on.
    assert!(quads[0].area() > 0.9 * 4.0 * 3.0, "area {}", quads[0].area());
    assert_conservative(&cooked);
}

#[test]
fn single_sided_plane_gives_a_patch_on_it() {
    let cooked = cook_evaluated_with(common::square(), &VOXEL_AND_PANEL_SHAPES);
    let patches = of_shape(&cooked, Shape::Patches);
    assert!(!patches.is_empty(), "{:?}", cooked.report.notes);
    for c in patches.iter().flat_map(|p| p.corners) {
        assert!(
            c[1].abs() < 1e-6 && c[0].abs() <= 1.0 && c[2].abs() <= 1.0,
            "corner {c:?} is off the plane"
        );
    }
    assert!(patches[0].area() > 0.9 * 4.0, "area {}", patches[0].area());
    let q = cooked.report.quality.unwrap();
    assert_eq!(q.false_pixels, 0, "{q:?}");
}

/// A patch's corners are new points: 100 km out, writing them as f32 may move them 0.008 off
/// the plane they lie on, so there the plane is left to the other pieces.
#[test]
fn a_single_sided_plane_far_from_the_origin_gives_no_patch() {
    let turn = glam::Quat::from_rotation_x(0.5);
    for (offset, patches) in [(0.0, true), (1e5, false)] {
        let mut plane = common::square();
        for p in &mut plane.positions {
            *p = turn * *p + Vec3::splat(offset);
        }
        let cooked = cook_evaluated_with(plane, &VOXEL_AND_PANEL_SHAPES);
        assert_eq!(!of_shape(&cooked, Shape::Patches).is_empty(), patches, "at {offset}");
        assert_conservative(&cooked);
    }
}

#[test]
fn l_shaped_thin_wall_gives_two_quads() {
    let t = 0.05;
    let wall_a = cuboid(Vec3::new(-2.0, 0.0, 0.0), Vec3::new(2.0, 3.0, t), &[]);
    let wall_b = cuboid(Vec3::new(2.0 - t, 0.0, 0.0), Vec3::new(2.0, 3.0, 4.0), &[]);
    let cooked = cook_evaluated_with(concat(&[wall_a, wall_b]), &VOXEL_AND_PANEL_SHAPES);
    let quads = of_shape(&cooked, Shape::Quads);
    assert_eq!(quads.len(), 2, "{quads:?}");
    let t = f64::from(t);
    let in_a = |c: [f64; 3]| c[2] > 0.0 && c[2] < t;
    let in_b = |c: [f64; 3]| c[0] > 2.0 - t && c[0] < 2.0;
    assert!(quads.iter().any(|q| q.corners.iter().all(|&c| in_a(c))), "{quads:?}");
    assert!(quads.iter().any(|q| q.corners.iter().all(|&c| in_b(c))), "{quads:?}");
    assert_conservative(&cooked);
    assert!(cooked.report.quality.unwrap().coverage > 0.8);
}

#[test]
fn doorway_stays_open() {
    // A wall 4 wide, 3 high and 0.05 thick, with a doorway 1 wide and 2 high in the middle.
    let t = 0.05;
    let wall = concat(&[
        cuboid(Vec3::new(-2.0, 0.0, 0.0), Vec3::new(-0.5, 3.0, t), &[]),
        cuboid(Vec3::new(0.5, 0.0, 0.0), Vec3::new(2.0, 3.0, t), &[]),
        cuboid(Vec3::new(-0.5, 2.0, 0.0), Vec3::new(0.5, 3.0, t), &[]),
    ]);
    let cooked = cook_evaluated_with(wall.clone(), &VOXEL_AND_PANEL_SHAPES);
    assert!(!of_shape(&cooked, Shape::Quads).is_empty());
    assert_conservative(&cooked);
    // Face on, every pixel whose centre is in the doorway (one pixel in from its edges) stays
    // uncovered, while most of the wall is covered.
    let (center, radius) = wall.bounding_sphere();
    let view = View::new(DVec3::Z, center, radius, 256);
    let original = coverage_mask(&view, &wall, None);
    let occluder = coverage_mask(&view, &cooked.occluder.mesh(), None);
    let lo = view.project(DVec3::new(-0.5, 0.0, 0.0));
    let hi = view.project(DVec3::new(0.5, 2.0, 0.0));
    let bit = |mask: &[u64], i: usize| mask[i / 64] >> (i % 64) & 1 == 1;
    let mut doorway = 0;
    for y in 0..256 {
        for x in 0..256 {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            if px > lo.x + 1.0 && px < hi.x - 1.0 && py > lo.y + 1.0 && py < hi.y - 1.0 {
                let i = y * 256 + x;
                assert!(!bit(&original, i), "the doorway is open in the original");
                assert!(
                    !bit(&occluder, i),
                    "the occluder covers the doorway at pixel ({x}, {y})"
                );
                doorway += 1;
            }
        }
    }
    assert!(doorway > 1000, "{doorway} doorway pixels checked");
    let seen = (0..256 * 256).filter(|&i| bit(&original, i)).count();
    let covered = (0..256 * 256)
        .filter(|&i| bit(&original, i) && bit(&occluder, i))
        .count();
    assert!(covered as f64 > 0.8 * seen as f64, "covered {covered} of {seen}");
}
