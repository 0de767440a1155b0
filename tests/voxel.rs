//! Voxel stages against plain definitions: surface voxels against brute-force overlap, and the
//! inside classification against the winding number summed triangle by triangle.

mod common;
use common::{cuboid, torus};
use glam::Vec3;
use occluder_cook::mesh::topology::orient_closed_components;
use occluder_cook::voxel::{Grid, InsideMethod, surface, winding::direct};

#[test]
fn winding_classification_matches_definition_on_open_and_closed_meshes() {
    for mut mesh in [
        torus(1.0, 0.4, 24, 12),
        cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[2]),
        cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[1, 3]),
    ] {
        let topology = orient_closed_components(&mut mesh);
        let (lo, hi) = mesh.bounds();
        let grid = Grid::fit(lo, hi, 20);
        let solid = common::solid(InsideMethod::Winding, &mesh, &topology, &grid, None);
        let mut differ = 0;
        for (i, &s) in solid.iter().enumerate() {
            let [x, y, z] = grid.coords(i);
            differ += usize::from(s != (direct(&mesh, grid.center(x, y, z)) >= 0.5));
        }
        assert_eq!(differ, 0, "{differ} of {} voxels differ", solid.len());
    }
}

#[test]
fn parity_equals_winding_on_a_watertight_mesh() {
    let mut mesh = torus(1.0, 0.4, 24, 12);
    let topology = orient_closed_components(&mut mesh);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 32);
    let parity = common::solid(InsideMethod::Parity, &mesh, &topology, &grid, None);
    let winding = common::solid(InsideMethod::Winding, &mesh, &topology, &grid, None);
    assert_eq!(parity, winding);
    assert!(parity.iter().any(|&v| v));
}

#[test]
fn surface_voxels_are_the_touched_ones_within_the_slack() {
    let mesh = torus(1.0, 0.4, 16, 8);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 16);
    let voxels = surface::voxelize(&mesh, &grid);
    let touched = |x, y, z, half: f64| {
        let half = [grid.voxel_size * half; 3];
        (0..mesh.triangles.len()).any(|t| {
            let tri = mesh.corners(t).map(|p| p.as_dvec3().to_array());
            surface::triangle_box_overlap(grid.center(x, y, z).to_array(), half, &tri)
        })
    };
    let slack = f64::from(surface::SLACK);
    for (i, &v) in voxels.iter().enumerate() {
        let [x, y, z] = grid.coords(i);
        // Every voxel a triangle touches is marked; a marked one is touched within the slack.
        if touched(x, y, z, 0.5) {
            assert!(v, "voxel {x},{y},{z} is touched but not marked");
        }
        if v {
            assert!(
                touched(x, y, z, 0.5 + 2.0 * slack),
                "voxel {x},{y},{z} is marked but not touched"
            );
        }
    }
    assert!(voxels.iter().any(|&v| v));
}
