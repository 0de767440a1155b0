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
