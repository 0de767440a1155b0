//! The preview sheet of a baked level: a top view of the placed meshes, each tinted by the batch
//! its occluder went into, and three cameras of the cull test as a player would see the level,
//! with the instances the occluder culls there seen through the walls in orange (red where they
//! were visible in truth: wrongly culled).

use super::cull::{self, Frame};
use super::{Level, MeshRef};
use crate::eval::preview::{BACKGROUND, CAPTION_PIXELS, FALSE_PIXEL, VIEW_PIXELS, legend, place_view, text};
use crate::geom::camera::View;
use crate::mesh::{Mesh, point_bounds};
use glam::DVec3;
use image::{Rgb, RgbImage};
use std::collections::HashMap;

/// What the caption says.
pub struct LevelCaption {
    pub name: String,
    pub instances: usize,
    pub batches: usize,
    /// Occluder triangles over all batches.
    pub triangles: usize,
    /// The bake's own cull test: culled share, wrongly culled instances and cameras. None: the
    /// sheet's three cameras give them, and the caption says so.
    pub cull: Option<(f64, usize, usize)>,
}

/// Cameras drawn.
const SHOTS: usize = 3;
/// The cull test's depth buffer width, as `level.cull_cameras` runs it.
pub const CULL_PIXELS: usize = 128;
const CULLED: [f64; 3] = [240.0, 140.0, 20.0];
const BATCH_COLOURS: [[f64; 3]; 6] = [
    [40.0, 110.0, 230.0],
    [30.0, 170.0, 90.0],
    [170.0, 60.0, 200.0],
    [20.0, 170.0, 190.0],
    [200.0, 170.0, 20.0],
    [120.0, 120.0, 240.0],
];

/// The sheet of `level` (its unique `meshes`), baked into `occluder` (every batch), whose
/// batches hold the instances listed in `batches`.
pub fn sheet(
    level: &Level,
    meshes: &HashMap<&MeshRef, Mesh>,
    occluder: &Mesh,
    batches: &[Vec<usize>],
    caption: &LevelCaption,
) -> Result<RgbImage, String> {
    let boxes = cull::instance_bounds(level, meshes);
    let all: Vec<usize> = (0..boxes.len()).collect();
    let side = VIEW_PIXELS as u32;
    let mut image = RgbImage::from_pixel(2 * side, 2 * side + CAPTION_PIXELS, BACKGROUND);

    let (lo, hi) = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
    let top = View::new(
        DVec3::Y,
        (lo + hi) * 0.5,
        ((hi - lo).length() * 0.5).max(1e-9),
        VIEW_PIXELS,
    );
    let mut batch_of = vec![None; level.instances.len()];
    for (b, group) in batches.iter().enumerate() {
        for &i in group {
            if let Some(slot) = batch_of.get_mut(i) {
                *slot = Some(BATCH_COLOURS[b % BATCH_COLOURS.len()]);
            }
        }
    }
    let frame = cull::render_instances(&top, level, meshes, &boxes, &all);
    place_view(
        &mut image,
        0,
        &compose(&frame, None, |i| batch_of[i]),
        "top: instances by batch",
    );

    let test = cull::cull_eval(level, meshes, occluder, SHOTS, CULL_PIXELS, None)?;
    let near = cull::near_plane(&boxes);
    for (c, shot) in test.shots.iter().enumerate() {
        let view = shot.view(VIEW_PIXELS, near);
        let scene = cull::render_instances(&view, level, meshes, &boxes, &all);
        let hidden = cull::render_instances(&view, level, meshes, &boxes, &shot.culled);
        let tint = |i: usize| match shot.wrongly_culled.contains(&i) {
            true => FALSE_PIXEL.0.map(f64::from),
            false => CULLED,
        };
        let pixels = compose(&scene, Some(&hidden), |i| Some(tint(i)));
        let name = format!("camera {}: {} culled", c + 1, shot.culled.len());
        place_view(&mut image, c + 1, &pixels, &name);
    }

    let y = 2 * side + 8;
    let entries = [("culled", CULLED), ("wrongly culled", FALSE_PIXEL.0.map(f64::from))];
    let legend_left = legend(&mut image, 2 * side - 8, y, &entries);
    let fits = (legend_left.saturating_sub(16) / 16) as usize;
    text(
        &mut image,
        8,
        y,
        2,
        &caption.name.chars().take(fits).collect::<String>(),
    );
    let placed = format!(
        "{} instances, {} batches, {} occluder triangles",
        caption.instances, caption.batches, caption.triangles
    );
    text(&mut image, 8, y + 26, 1, &placed);
    let (share, wrong, cameras, whose) = match caption.cull {
        Some((share, wrong, cameras)) => (share, wrong, cameras, "cameras"),
        None => (test.culled_share, test.wrongly_culled, test.cameras, "cameras shown"),
    };
    let figures = format!(
        "culled {:.1}% of the instances in view, {wrong} wrongly ({cameras} {whose})",
        share * 100.0
    );
    text(&mut image, 8, y + 42, 1, &figures);
    Ok(image)
}

/// A frame's pixels, rows from the top: each instance shaded in grey, tinted by `tint` where it
/// gives a colour; where `through` (a render of other instances) shows one, that one's tint
/// shows through, half strength.
fn compose(frame: &Frame, through: Option<&Frame>, tint: impl Fn(usize) -> Option<[f64; 3]>) -> Vec<Rgb<u8>> {
    let n = VIEW_PIXELS;
    let mut pixels = Vec::with_capacity(n * n);
    for row in (0..n).rev() {
        for p in row * n..(row + 1) * n {
            let mut rgb = match frame.instance[p] {
                u32::MAX => BACKGROUND.0.map(f64::from),
                i => {
                    let grey = [f64::from(frame.light[p]) * 200.0; 3];
                    match (through.is_none()).then(|| tint(i as usize)).flatten() {
                        Some(c) => [0, 1, 2].map(|k| 0.45 * grey[k] + 0.55 * c[k]),
                        None => grey,
                    }
                }
            };
            let hidden = through.map(|t| t.instance[p]).filter(|&i| i != u32::MAX);
            if let Some(c) = hidden.and_then(|i| tint(i as usize)) {
                rgb = [0, 1, 2].map(|k| 0.5 * rgb[k] + 0.5 * c[k]);
            }
            pixels.push(Rgb(rgb.map(|v| v.clamp(0.0, 255.0) as u8)));
        }
    }
    pixels
}
