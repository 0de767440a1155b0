//! Surface pieces: the mesh's own flat regions as occluder pieces, on shells with no volume
//! (where boxes and quads find nothing), and the whole surface when it fits in the budget.

mod common;
use common::{VOXEL_AND_PANEL_SHAPES, cook_evaluated, cook_evaluated_with, cuboid, defaults};
use glam::Vec3;
use occluder_cook::cook::Cooked;
use occluder_cook::eval::evaluate;
use occluder_cook::mesh::{Mesh, topology::orient_closed_components};

/// Views of the denser judge for open shells: a slot shows from few directions.
const JUDGE_VIEWS: usize = 512;

/// Half a cylinder of radius 1 around z, from z = -1 to 1, open below y = 0 and at its ends:
/// `around` strips of `along` quads, the quads of strips `window.0` and rows `window.1` left out.
fn half_cylinder(around: u32, along: u32, window: ([u32; 2], [u32; 2])) -> Mesh {
    let mut mesh = Mesh::default();
    for j in 0..=along {
        for i in 0..=around {
            let angle = std::f32::consts::PI * i as f32 / around as f32;
            let z = -1.0 + 2.0 * j as f32 / along as f32;
            mesh.positions.push(Vec3::new(angle.cos(), angle.sin(), z));
        }
    }
    let at = |i: u32, j: u32| j * (around + 1) + i;
    let ([i0, i1], [j0, j1]) = window;
    for j in 0..along {
        for i in 0..around {
            if (i0..i1).contains(&i) && (j0..j1).contains(&j) {
                continue;
            }
            mesh.triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            mesh.triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh
}

/// Judges `cooked` from [`JUDGE_VIEWS`] directions: its non-below false pixels.
fn judged_false_pixels(mesh: &Mesh, cooked: &Cooked) -> u64 {
    let mut mesh = mesh.clone();
    let topology = orient_closed_components(&mut mesh);
    let mut eval = defaults().eval;
    eval.views = JUDGE_VIEWS;
    let q = evaluate(&mesh, &topology.boundary, &cooked.occluder.mesh(), &eval, None).expect("evaluates");
    q.false_pixels_non_below
}

#[test]
fn an_open_curved_shell_with_a_window_is_covered_by_its_own_surface() {
    // 160 strips of 12 quads (3,780 triangles with the window out): the strips' flat regions
    // take 2 triangles each, more than the budget holds, so the selection chooses among them.
    let shell = half_cylinder(160, 12, ([60, 100], [4, 8]));
    let cooked = cook_evaluated(shell.clone());
    let q = cooked.report.quality.clone().expect("evaluated");
    println!(
        "half cylinder: {} triangles, {} surface pieces, coverage {:.1}%, {} non-below false pixels",
        q.occluder_triangles,
        cooked.report.occluder.surface_pieces,
        q.coverage * 100.0,
        q.false_pixels_non_below
    );
    assert!(cooked.report.occluder.surface_pieces > 0);
    assert!(q.occluder_triangles <= 256);
    assert_eq!(q.false_pixels_non_below, 0, "{q:?}");
    assert_eq!(judged_false_pixels(&shell, &cooked), 0, "at {JUDGE_VIEWS} views");
    assert_eq!(q.outside_samples, 0.0);
    assert!(q.coverage >= 0.6, "coverage {:.3}", q.coverage);
    // Without surface pieces a shell with no volume has next to nothing.
    let without = cook_evaluated_with(shell, &VOXEL_AND_PANEL_SHAPES);
    let before = without.report.quality.expect("evaluated").coverage;
    println!("half cylinder without surface pieces: coverage {:.1}%", before * 100.0);
    assert!(q.coverage > before + 0.2, "{} against {before}", q.coverage);
}

#[test]
fn a_coarse_shell_fits_in_the_budget_whole_and_covers_all_of_itself() {
    let shell = half_cylinder(24, 6, ([8, 16], [2, 4]));
    let cooked = cook_evaluated(shell.clone());
    let q = cooked.report.quality.clone().expect("evaluated");
    // 24 strips, the 8 with the window in two pieces: 32 regions of 2 triangles.
    assert_eq!(q.occluder_triangles, 64, "{:?}", cooked.report.occluder);
    assert_eq!(cooked.report.occluder.boxes + cooked.report.occluder.quads, 0);
    assert!(q.coverage > 0.999, "coverage {}", q.coverage);
    assert_eq!(q.false_pixels, 0, "{q:?}");
    assert_eq!(judged_false_pixels(&shell, &cooked), 0, "at {JUDGE_VIEWS} views");
}

#[test]
fn three_faces_of_a_tetrahedron_are_their_own_occluder() {
    let tetrahedron = Mesh {
        positions: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ],
        // The face opposite the origin is missing.
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2]],
    };
    let cooked = cook_evaluated(tetrahedron);
    let q = cooked.report.quality.expect("evaluated");
    assert!(q.occluder_triangles <= 4, "{} triangles", q.occluder_triangles);
    assert!(q.coverage > 0.999, "coverage {}", q.coverage);
    assert_eq!(q.false_pixels, 0);
}

#[test]
fn a_closed_box_is_covered_by_its_own_faces() {
    let cooked = cook_evaluated(cuboid(Vec3::ZERO, Vec3::new(3.0, 1.0, 2.0), &[]));
    let q = cooked.report.quality.expect("evaluated");
    // Five double-sided faces hide what the box hides from every side.
    assert!(q.occluder_triangles <= 12, "{q:?}");
    assert!(q.coverage > 0.999, "coverage {}", q.coverage);
    assert_eq!(q.false_pixels, 0);
    assert_eq!(q.outside_samples, 0.0);
}

#[test]
fn a_curved_closed_mesh_loses_no_coverage_to_surface_pieces() {
    // A torus has no flat region larger than a quad: boxes and quads still do the work.
    let torus = common::torus(1.0, 0.45, 64, 32);
    let with = cook_evaluated(torus.clone()).report.quality.expect("evaluated");
    let without = cook_evaluated_with(torus, &VOXEL_AND_PANEL_SHAPES)
        .report
        .quality
        .expect("evaluated");
    assert_eq!(with.false_pixels, 0);
    assert!(
        with.coverage >= without.coverage - 1e-9,
        "{} < {}",
        with.coverage,
        without.coverage
    );
}

#[test]
fn a_mesh_its_own_surface_covers_skips_the_voxel_stages() {
    let cooked = cook_evaluated(half_cylinder(24, 6, ([8, 16], [2, 4])));
    let r = &cooked.report;
    assert!(
        r.notes.iter().any(|n| n.contains("cook.surface_enough")),
        "{:?}",
        r.notes
    );
    assert_eq!(r.timings_ms.get("inside"), 0.0);
    assert_eq!(r.voxels.inner, 0);
    assert!(r.gpu_stages.is_empty());
    // Asked for all of the silhouette, the fine shell's pieces fall short: the voxel stages run,
    // and the occluder is what they and the pieces give together.
    let mut settings = defaults();
    settings.cook.surface_enough = 1.0;
    let shell = half_cylinder(160, 12, ([60, 100], [4, 8]));
    let cooked = occluder_cook::cook::cook(shell, Default::default(), 0.0, &settings, false).expect("cooks");
    assert!(cooked.report.timings_ms.get("inside") > 0.0);
    assert!(!cooked.report.notes.iter().any(|n| n.contains("cook.surface_enough")));
    // A curved closed mesh's flat regions hold too little of its area to be tried alone.
    let torus = cook_evaluated(common::torus(1.0, 0.45, 48, 24));
    assert!(torus.report.timings_ms.get("inside") > 0.0);
    assert!(torus.report.voxels.inner > 0);
}
