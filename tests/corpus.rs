//! The shared corpus at the default settings: closed meshes show no false pixel from any view,
//! open ones none from views that are not below them, judged from 4,096 directions of 512
//! pixels as well as the cook's own 64. Coverage is printed, for the record.

mod common;
use occluder_cook::config::Settings;
use occluder_cook::cook::cook;
use occluder_cook::eval::{Quality, ViewSet, evaluate};
use occluder_cook::geom::openings::{boundary_loops, join_loops};
use occluder_cook::mesh::{IngestLimits, load_file, topology::orient_closed_components};
use occluder_cook::occluder::Shape;
use std::path::Path;

const CLOSED: [&str; 5] = ["spot.obj", "cow.obj", "fandisk.obj", "homer.obj", "duck.glb"];
/// Every open mesh of the corpus, with its coverage (%) at 64 views when the floor was set; the
/// test allows a point less. Surface pieces (the mesh's own flat regions) lifted most of them.
const OPEN: [(&str, f64); 12] = [
    // Cameras in the gap between its lid and rim see into the body: what shows only through
    // the gap counts as seen (33.3% before they were placed there, with false pixels at 4,096
    // views).
    ("teapot.obj", 24.58),
    ("sphere-with-hole.stl", 97.55),
    ("suzanne.obj", 96.38),
    ("kenney-building-small-a.glb", 99.67),
    ("kenney-building-small-c.glb", 99.65),
    ("kenney-building-garage.glb", 99.90),
    ("bunny-holes.obj", 66.71),
    ("monkey.glb", 96.14),
    ("soup.stl", 99.37),
    ("2cylinder-engine.glb", 70.40),
    ("wallhole.obj", 100.0),
    ("testscene/TestScene.gltf", 97.87),
];

/// What the surface-pieces issue asks of open meshes: (mesh, least coverage %, most triangles).
const TARGETS: [(&str, f64, usize); 8] = [
    ("sphere-with-hole.stl", 95.0, 256),
    ("suzanne.obj", 85.0, 256),
    ("monkey.glb", 85.0, 256),
    ("kenney-building-small-a.glb", 97.0, 128),
    ("kenney-building-small-c.glb", 97.0, 128),
    ("kenney-building-garage.glb", 97.0, 128),
    ("2cylinder-engine.glb", 65.0, 256),
    ("bunny-holes.obj", 66.0, 256),
];

/// Views and pixels across of the denser judge: a crack or a slot shows only from a few
/// directions, which 64 views miss. Lines through the teapot's lid gap reach its inside from a
/// narrow band of directions: 1,024 views of 256 pixels missed the 3 pixels its occluder hid
/// there before cameras were placed in the gap.
const JUDGE: (usize, usize) = (4096, 512);

fn cook_corpus_mesh(name: &str) -> Option<Quality> {
    Some(cook_file(&common::corpus()?.join(name)).0)
}

/// Cooks with evaluation at the default settings; returns the quality and the cooked occluder.
fn cook_file(path: &Path) -> (Quality, occluder_cook::cook::Cooked) {
    cook_file_with(path, &common::defaults())
}

/// [`cook_file`] at `settings`.
fn cook_file_with(path: &Path, settings: &Settings) -> (Quality, occluder_cook::cook::Cooked) {
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    let (mesh, stats) = load_file(path, &IngestLimits::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    let cooked = cook(mesh, stats, 0.0, settings, true).expect("cooks");
    let q = cooked.report.quality.clone().expect("evaluated");
    println!(
        "{name}: {} triangles, coverage {:.1}%, false pixels {} / {} non-below, outside {:.2}%",
        q.occluder_triangles,
        q.coverage * 100.0,
        q.false_pixels,
        q.false_pixels_non_below,
        q.outside_samples * 100.0
    );
    (q, cooked)
}

/// `cooked`'s occluder judged again by [`JUDGE`], on the CPU.
fn judge_densely(path: &Path, cooked: &occluder_cook::cook::Cooked) -> Quality {
    let (mut mesh, _) = load_file(path, &IngestLimits::default()).expect("loads");
    let topology = orient_closed_components(&mut mesh);
    let mut settings = common::defaults().eval;
    (settings.views, settings.pixels) = JUDGE;
    let judged =
        evaluate(&mesh, &topology.boundary, &cooked.occluder.mesh(), &settings, None).expect("the CPU evaluates");
    println!(
        "{}: at {JUDGE:?} views and pixels, false pixels {} / {} non-below",
        path.display(),
        judged.false_pixels,
        judged.false_pixels_non_below
    );
    judged
}

#[test]
fn closed_meshes_have_no_false_pixels() {
    for name in CLOSED {
        let Some(dir) = common::corpus() else { return };
        let (q, cooked) = cook_file(&dir.join(name));
        assert_eq!(q.false_pixels, 0, "{name}");
        assert_eq!(
            judge_densely(&dir.join(name), &cooked).false_pixels,
            0,
            "{name} at {JUDGE:?} views and pixels"
        );
        assert_eq!(q.outside_samples, 0.0, "{name}");
        assert!(q.occluder_triangles <= 256, "{name}");
        assert!(q.coverage >= 0.8, "{name}: coverage {}", q.coverage);
    }
}

/// Fandisk's flat regions bend within the surface pieces' tolerance. Its pieces alone, new
/// triangles across a dip included, stood out of the solid where a view grazes them: 5 false
/// pixels at 64 views, all from below, before they were moved in under their regions.
#[test]
fn a_closed_meshs_surface_pieces_alone_show_no_false_pixel() {
    let Some(dir) = common::corpus() else { return };
    let mut settings = common::defaults();
    settings.cook.shapes = vec![Shape::Surface];
    let (q, cooked) = cook_file_with(&dir.join("fandisk.obj"), &settings);
    assert!(cooked.report.occluder.surface_pieces > 0 && q.coverage > 0.5, "{q:?}");
    assert_eq!(q.false_pixels, 0);
}

#[test]
fn open_meshes_have_no_false_pixels_from_above_and_keep_their_coverage() {
    for (name, coverage) in OPEN {
        let Some(dir) = common::corpus() else { return };
        let (q, cooked) = cook_file(&dir.join(name));
        assert_eq!(q.false_pixels_non_below, 0, "{name}");
        let judged = judge_densely(&dir.join(name), &cooked);
        assert_eq!(
            judged.false_pixels_non_below, 0,
            "{name} at {JUDGE:?} views and pixels: {judged:?}"
        );
        assert!(
            q.coverage * 100.0 >= coverage - 1.0,
            "{name}: coverage {:.2}% under the floor {:.2}%",
            q.coverage * 100.0,
            coverage - 1.0
        );
        if let Some(&(_, least, most)) = TARGETS.iter().find(|t| t.0 == name) {
            assert!(
                q.coverage * 100.0 >= least,
                "{name}: coverage {:.2}% under {least}%",
                q.coverage * 100.0
            );
            assert!(
                q.occluder_triangles <= most,
                "{name}: {} triangles",
                q.occluder_triangles
            );
        }
    }
}

/// missingFace.ascii.stl is three faces of a tetrahedron: its own three triangles are the exact
/// occluder.
#[test]
fn three_faces_of_a_tetrahedron_are_covered_by_themselves() {
    let Some(dir) = common::corpus() else { return };
    let (q, _) = cook_file(&dir.join("broken/missingFace.ascii.stl"));
    assert!(q.occluder_triangles <= 4, "{q:?}");
    assert!(q.coverage > 0.999, "{q:?}");
    assert_eq!(q.false_pixels, 0);
}

/// The teapot's lid sits in its rim across a gap 0.1 wide, through which its inside shows. With
/// smallest_hole 0.15 the gap counts as closed, and the occluder is judged against the teapot
/// with its two rim loops at y = 2.4 joined.
#[test]
fn the_teapot_with_its_lid_gap_closed_is_covered() {
    let Some(dir) = common::corpus() else { return };
    let (mut teapot, stats) = load_file(&dir.join("teapot.obj"), &IngestLimits::default()).expect("loads");
    let mut settings = common::defaults();
    settings.cook.smallest_hole = 0.15;
    let cooked = cook(teapot.clone(), stats, 0.0, &settings, false).expect("cooks");
    let closed = &cooked.report.openings_closed;
    for o in closed {
        println!("teapot: closed a {} {:.3} wide at {:?}", o.kind, o.width, o.position);
    }
    assert!(closed.iter().any(|o| o.kind == "gap" && o.width < 0.15), "{closed:?}");
    assert!(cooked.report.notes.iter().any(|n| n.contains("smallest_hole")));
    let topology = orient_closed_components(&mut teapot);
    let rims: Vec<Vec<u32>> = boundary_loops(&topology.boundary)
        .into_iter()
        .filter(|l| l.iter().all(|&v| (teapot.positions[v as usize].y - 2.4).abs() < 1e-4))
        .filter(|l| l.len() > 20)
        .collect();
    assert_eq!(rims.len(), 2, "the body's rim and the lid's");
    join_loops(&mut teapot, &rims[0], &rims[1]);
    let topology = orient_closed_components(&mut teapot);
    for (views, pixels) in [(64, settings.eval.pixels), JUDGE] {
        let mut eval = settings.eval.clone();
        (eval.views, eval.pixels) = (views, pixels);
        let q = evaluate(&teapot, &topology.boundary, &cooked.occluder.mesh(), &eval, None).expect("evaluates");
        println!(
            "teapot, lid gap closed, {views} views: coverage {:.1}%, {} non-below false pixels",
            q.coverage * 100.0,
            q.false_pixels_non_below
        );
        assert_eq!(q.false_pixels_non_below, 0, "{views} views: {q:?}");
        assert!(q.coverage >= 0.75, "{views} views: {q:?}");
    }
}

/// Bunny-holes' holes are small: a piece can show through one only from a narrow cone of
/// directions, which the cameras placed in the openings catch. Suzanne's eye sockets are filled
/// by the eyes: those cameras must not eat her head.
#[test]
fn small_holes_show_nothing_and_leave_a_useful_occluder() {
    for name in ["bunny-holes.obj", "suzanne.obj"] {
        let Some(q) = cook_corpus_mesh(name) else { return };
        assert_eq!(q.false_pixels_non_below, 0, "{name}");
        assert!(q.coverage >= 0.6, "{name}: coverage {}", q.coverage);
    }
}

/// A room of walls 0.05 thick: a few quads cover it, from outside and from its centre.
#[test]
fn room_gets_few_quads_and_no_false_pixels() {
    let Some(levels) = common::levels() else { return };
    let path = levels.join("godot-rooms/room.glb");
    let (q, cooked) = cook_file(&path);
    assert!(q.occluder_triangles <= 48, "{q:?}");
    assert_eq!(q.false_pixels, 0);
    assert!(q.coverage >= 0.95, "coverage {}", q.coverage);
    let (mut mesh, _) = load_file(&path, &IngestLimits::default()).unwrap();
    let topology = orient_closed_components(&mut mesh);
    let mut settings = common::defaults().eval;
    settings.view_set = ViewSet::Inside;
    let inside =
        evaluate(&mesh, &topology.boundary, &cooked.occluder.mesh(), &settings, None).expect("the CPU evaluates");
    println!(
        "room from its centre: coverage {:.1}%, false pixels {}",
        inside.coverage * 100.0,
        inside.false_pixels
    );
    assert_eq!(inside.false_pixels, 0);
    assert!(inside.coverage >= 0.9, "coverage from inside {}", inside.coverage);
}

/// A whole level as one polygon soup: patches on its flat parts.
#[test]
fn pandora_as_one_mesh_gets_a_conservative_occluder() {
    let Some(levels) = common::levels() else { return };
    let (q, _) = cook_file(&levels.join("pandora/pandora.obj"));
    assert!(q.occluder_triangles > 0 && q.occluder_triangles <= 2000, "{q:?}");
    assert_eq!(q.false_pixels_non_below, 0);
}

/// Every file of the formats folder cooks with no false pixel, judged against the geometry that
/// `convert` writes of it, or is refused in one line.
#[test]
fn every_format_cooks_conservatively_or_is_refused_in_one_line() {
    let Some(dir) = common::corpus() else { return };
    let scratch = std::env::temp_dir().join(format!("occluder-cook-formats-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    let mut files: Vec<_> = std::fs::read_dir(dir.join("formats"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| occluder_cook::mesh::Format::from_extension(p).is_ok())
        .collect();
    files.sort();
    assert!(files.len() >= 8, "{files:?}");
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if let Err(e) = load_file(&path, &IngestLimits::default()) {
            let message = e.to_string();
            println!("{name}: refused: {message}");
            assert!(!message.contains('\n') && message.len() <= 200, "{name}: {message}");
            continue;
        }
        let (q, cooked) = cook_file(&path);
        let converted = scratch.join(format!("{name}.glb"));
        let (code, _, err) = common::cli(&["convert", path.to_str().unwrap(), converted.to_str().unwrap()]);
        assert_eq!(code, 0, "{name}: {err}");
        let judged = judge_densely(&converted, &cooked);
        let closed = cooked.report.input.topology.boundary_edges == 0;
        let (false_pixels, judged_false) = match closed {
            true => (q.false_pixels, judged.false_pixels),
            false => (q.false_pixels_non_below, judged.false_pixels_non_below),
        };
        assert_eq!((false_pixels, judged_false), (0, 0), "{name} (closed: {closed})");
        // The spider's legs are thinner than a voxel: its body alone covers 37%.
        assert!(q.coverage > 0.3, "{name}: coverage {}", q.coverage);
    }
    std::fs::remove_dir_all(&scratch).unwrap();
}
