//! The shared corpus at the default settings: closed meshes show no false pixel from any view,
//! open ones none from views that are not below them. Coverage is printed, for the record.

mod common;
use occluder_cook::cook::cook;
use occluder_cook::mesh::load_file;

const CLOSED: [&str; 5] = ["spot.obj", "cow.obj", "fandisk.obj", "homer.obj", "duck.glb"];
const OPEN: [&str; 5] = [
    "teapot.obj",
    "suzanne.obj",
    "kenney-building-small-a.glb",
    "kenney-building-small-c.glb",
    "kenney-building-garage.glb",
];

fn cook_corpus_mesh(name: &str) -> Option<occluder_cook::eval::Quality> {
    let corpus = common::corpus()?;
    let (mesh, stats) = load_file(&corpus.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    let cooked = cook(mesh, stats, 0.0, &common::defaults(), true);
    let q = cooked.report.quality.expect("evaluated");
    println!(
        "{name}: {} triangles, coverage {:.1}%, false pixels {} / {} non-below, outside {:.2}%",
        q.occluder_triangles,
        q.coverage * 100.0,
        q.false_pixels,
        q.false_pixels_non_below,
        q.outside_samples * 100.0
    );
    assert!(q.occluder_triangles <= 256, "{name}");
    Some(q)
}

#[test]
fn closed_meshes_have_no_false_pixels() {
    for name in CLOSED {
        let Some(q) = cook_corpus_mesh(name) else { return };
        assert_eq!(q.false_pixels, 0, "{name}");
        assert_eq!(q.outside_samples, 0.0, "{name}");
        assert!(q.coverage > 0.6, "{name}: coverage {}", q.coverage);
    }
}

#[test]
fn open_meshes_have_no_false_pixels_from_above() {
    for name in OPEN {
        let Some(q) = cook_corpus_mesh(name) else { return };
        assert_eq!(q.false_pixels_non_below, 0, "{name}");
    }
}

/// Known failure: a few pixels of one near-horizontal view see a box through the bunny's bottom
/// holes, which the exposure test's sampled views miss. Run with `--ignored` to see the count.
#[test]
#[ignore = "bunny-holes still shows a few false pixels in one non-below view"]
fn bunny_holes_has_no_false_pixels_from_above() {
    if let Some(q) = cook_corpus_mesh("bunny-holes.obj") {
        assert_eq!(q.false_pixels_non_below, 0);
    }
}
