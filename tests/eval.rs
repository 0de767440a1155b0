//! The quality figures judge the whole occluder: a part beside the original, outside the frame
//! of its bounding sphere, counts in every view that sees it.

mod common;
use common::cuboid;
use glam::Vec3;
use occluder_cook::eval::evaluate;

#[test]
fn an_occluder_beside_the_mesh_shows_false_pixels_from_every_side() {
    let original = cuboid(Vec3::splat(-0.5), Vec3::splat(0.5), &[]);
    // A column beside the cube, wholly outside its bounding sphere, and taller than the cube,
    // so that no view hides it behind the cube.
    let beside = cuboid(Vec3::new(2.0, -1.0, -0.5), Vec3::new(3.0, 1.0, 0.5), &[]);
    let mut settings = common::defaults().eval;
    settings.pixels = 64;
    let q = evaluate(&original, &[], &beside, &settings, None).expect("the CPU evaluates");
    // At the original's scale (64 pixels over the sphere's diameter, √3) the column shows at
    // least one 1 × 1 face, some 1,300 pixels, in each of the 64 views.
    let per_unit = 64.0 / 3f64.sqrt();
    let at_least = (q.views as f64 * 0.9 * per_unit * per_unit) as u64;
    println!(
        "{} false pixels over {} views (at least {at_least})",
        q.false_pixels, q.views
    );
    assert!(q.false_pixels >= at_least, "{q:?}");
    // An occluder inside the frame is judged as before: its own figures, no margin.
    let inside = cuboid(Vec3::splat(-0.25), Vec3::splat(0.25), &[]);
    let q = evaluate(&original, &[], &inside, &settings, None).expect("the CPU evaluates");
    assert_eq!(q.false_pixels, 0, "{q:?}");
    assert!(q.coverage > 0.2, "{q:?}");
}

/// The preview sheet: four views and a caption, false pixels in red exactly where the occluder
/// shows in front of or beside the original, none for one inside it.
#[test]
fn the_preview_paints_false_pixels_red_and_only_those() {
    use occluder_cook::eval::preview::{Caption, Piece, pieces_of_mesh, sheet};
    let original = cuboid(Vec3::splat(-0.5), Vec3::splat(0.5), &[]);
    let caption = |triangles_out| Caption {
        openings: Vec::new(),
        name: "cube".into(),
        triangles_in: 12,
        triangles_out,
        judged: None,
    };
    let solid = |mesh| pieces_of_mesh(&mesh, Piece::Solid);
    // Red in the views, above the caption (whose key has a red swatch).
    let views = 2 * occluder_cook::eval::preview::VIEW_PIXELS as u32;
    let red = |image: &image::RgbImage| {
        image
            .enumerate_pixels()
            .filter(|(_, y, p)| *y < views && p.0 == [220, 20, 30])
            .count()
    };
    let inside = solid(cuboid(Vec3::splat(-0.4), Vec3::splat(0.4), &[]));
    let (image, false_pixels) = sheet(&original, &inside, &caption(12));
    assert_eq!((false_pixels, red(&image)), (0, 0));
    assert!(image.width() >= 640 && image.height() > image.width());
    // Sticking out of the cube on +x: seen from the front, the top and three-quarters.
    let sticking_out = solid(cuboid(Vec3::splat(-0.4), Vec3::new(0.9, 0.4, 0.4), &[]));
    let (image, false_pixels) = sheet(&original, &sticking_out, &caption(12));
    println!("{false_pixels} false pixels, {} red", red(&image));
    assert!(false_pixels > 1000, "{false_pixels}");
    assert_eq!(
        red(&image) as u64,
        false_pixels,
        "every false pixel is red, and nothing else"
    );
    let png = occluder_cook::eval::preview::png(&image);
    assert_eq!(&png[1..4], b"PNG");
    // Openings that smallest_hole closed are outlined, in every view that sees them.
    let outlined = |image: &image::RgbImage| {
        image
            .enumerate_pixels()
            .filter(|(_, y, p)| *y < views && p.0 == [200, 0, 200])
            .count()
    };
    assert_eq!(outlined(&image), 0);
    let ring = vec![[-0.3, 0.5, -0.3], [0.3, 0.5, -0.3], [0.3, 0.5, 0.3], [-0.3, 0.5, 0.3]];
    let with_opening = Caption {
        openings: vec![ring],
        ..caption(12)
    };
    let (image, _) = sheet(&original, &inside, &with_opening);
    assert!(outlined(&image) > 200, "{} outlined", outlined(&image));
}

/// Coverage is over the views that see the original. Where none does (a flat square judged from
/// a cube map at its own centre, every face edge-on to it), the figures say so: no views seeing,
/// coverage 0 and not a mean of nothing.
#[test]
fn coverage_is_over_the_views_that_see_the_original_and_none_is_said() {
    use occluder_cook::eval::ViewSet;
    let square = common::square();
    let mut settings = common::defaults().eval;
    settings.pixels = 64;
    settings.view_set = ViewSet::Inside;
    let q = evaluate(&square, &[], &square, &settings, None).expect("the CPU evaluates");
    assert_eq!((q.views, q.views_seeing), (6, 0), "{q:?}");
    assert_eq!((q.coverage.to_bits(), q.coverage_min.to_bits()), (0, 0), "{q:?}");
    // From outside, every view sees it but those edge-on; coverage is theirs.
    settings.view_set = ViewSet::Outside;
    let q = evaluate(&square, &[], &square, &settings, None).expect("the CPU evaluates");
    assert!(q.views_seeing > 0 && q.views_seeing <= q.views, "{q:?}");
    assert_eq!((q.coverage, q.coverage_min), (1.0, 1.0), "{q:?}");
}
