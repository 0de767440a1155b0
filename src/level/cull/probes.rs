//! Probe culling: how much of what a map hides an occluder culls, from where players stand.
//!
//! Boxes (probes) stand in the map's free space. From each camera the occluder fills a runtime's
//! low-resolution depth buffer (wide, a 90° horizontal field of view, as conservative as
//! [`Occluder::depth`]), and a probe whose screen rectangle lies wholly behind it is
//! culled. The truth renders the whole map at a higher resolution: a probe is visible when any
//! of its pixels lies nearer than the map there. The same test with the map's own triangles as
//! the occluder is the limit: what no occluder can beat at that buffer size.
//!
//! A wide buffer is the middle rows of a square one: the square view's rows above and below
//! are not looked at.

use super::{ScreenBox, box_on_screen, depth_tolerance, fully_behind};
use crate::geom::camera::View;
use crate::geom::raster::covered::Occluder;
use crate::geom::raster::{rasterize, rasterize_mesh};
use crate::level::free_space::{Pose, Probe};
use crate::mesh::{Mesh, point_bounds};
use crate::occluder::{WorldBox, merge::merge};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

/// A depth buffer's size: width and height in pixels; the height at most the width.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Buffer {
    pub width: usize,
    pub height: usize,
}

impl Buffer {
    /// The view of `pose` in a square `width` wide, and the rows of it that this buffer is.
    fn view(&self, pose: &Pose, near: f64) -> (View, [usize; 2]) {
        let view = View::perspective(pose.eye, -pose.forward, self.width, near);
        let first = (self.width - self.height) / 2;
        (view, [first, first + self.height - 1])
    }
}

/// How an occluder fared over every camera's probes in view.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ProbeCounts {
    /// Probes in view that the map hides.
    pub probes_hidden: usize,
    /// Probes hidden and culled.
    pub probes_culled: usize,
    /// Probes culled while visible: must be 0.
    pub probes_wrongly_culled: usize,
    /// Culled over hidden.
    pub culled_share: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ProbeReport {
    pub cameras: usize,
    pub probes: usize,
    /// Probe views over all cameras: a probe counts once for each camera that has it in view.
    pub probes_in_view: usize,
    pub buffer: Buffer,
    pub truth: Buffer,
    pub occluder_triangles: usize,
    pub map_triangles: usize,
    #[serde(flatten)]
    pub occluder: ProbeCounts,
    /// The map's own triangles as the occluder.
    pub limit: ProbeCounts,
}

/// Per camera: which probes are in view, and which of those the map hides, the occluder culls
/// and the map culls.
#[derive(Default)]
struct CameraTally {
    in_view: usize,
    occluder: ProbeCounts,
    limit: ProbeCounts,
}

/// Tests `probes` from `cameras` against `occluder`, and against the map's own triangles.
pub fn probe_eval(
    map: &Mesh,
    occluder: &Mesh,
    cameras: &[Pose],
    probes: &[Probe],
    buffer: Buffer,
    truth: Buffer,
) -> ProbeReport {
    let boxes: Vec<(DVec3, DVec3)> = probes
        .iter()
        .map(|p| (DVec3::from_array(p.lo), DVec3::from_array(p.hi)))
        .collect();
    let (lo, hi) = point_bounds(
        map.triangles_f64()
            .flatten()
            .chain(boxes.iter().flat_map(|&(l, h)| [l, h])),
    );
    let tolerance = depth_tolerance(lo, hi);
    let near = tolerance * 1e-3;
    let (covered, limit) = (Occluder::new(occluder), Occluder::new(map));
    let tallies: Vec<CameraTally> = cameras
        .par_iter()
        .map(|pose| {
            let (coarse, rows) = buffer.view(pose, near);
            let in_view: Vec<(usize, ScreenBox)> = boxes
                .iter()
                .enumerate()
                .filter_map(|(i, b)| Some((i, within_rows(box_on_screen(&coarse, b)?, rows)?)))
                .collect();
            let (fine, fine_rows) = truth.view(pose, near);
            let visible = visible_probes(&fine, fine_rows, map, &boxes, in_view.iter().map(|(i, _)| *i));
            let count = |depth: &[f32]| {
                let mut counts = ProbeCounts::default();
                for ((_, screen), &seen) in in_view.iter().zip(&visible) {
                    let culled = fully_behind(depth, buffer.width, screen, tolerance);
                    counts.probes_hidden += usize::from(!seen);
                    counts.probes_culled += usize::from(culled && !seen);
                    counts.probes_wrongly_culled += usize::from(culled && seen);
                }
                counts
            };
            CameraTally {
                in_view: in_view.len(),
                occluder: count(&covered.depth(&coarse)),
                limit: count(&limit.depth(&coarse)),
            }
        })
        .collect();
    let total = |pick: fn(&CameraTally) -> &ProbeCounts| {
        let mut sum = tallies
            .iter()
            .map(pick)
            .fold(ProbeCounts::default(), |a, b| ProbeCounts {
                probes_hidden: a.probes_hidden + b.probes_hidden,
                probes_culled: a.probes_culled + b.probes_culled,
                probes_wrongly_culled: a.probes_wrongly_culled + b.probes_wrongly_culled,
                culled_share: 0.0,
            });
        sum.culled_share = sum.probes_culled as f64 / sum.probes_hidden.max(1) as f64;
        sum
    };
    ProbeReport {
        cameras: cameras.len(),
        probes: probes.len(),
        probes_in_view: tallies.iter().map(|t| t.in_view).sum(),
        buffer,
        truth,
        occluder_triangles: occluder.triangles.len(),
        map_triangles: map.triangles.len(),
        occluder: total(|t| &t.occluder),
        limit: total(|t| &t.limit),
    }
}

/// The screen box cut to the buffer's rows; None when it lies wholly above or below them.
fn within_rows(mut screen: ScreenBox, [first, last]: [usize; 2]) -> Option<ScreenBox> {
    if screen.y[1] < first || screen.y[0] > last {
        return None;
    }
    screen.y = [screen.y[0].max(first), screen.y[1].min(last)];
    Some(screen)
}

/// For each probe of `in_view`, whether any of its pixels within `rows` lies nearer than the
/// map.
fn visible_probes(
    view: &View,
    [first, last]: [usize; 2],
    map: &Mesh,
    boxes: &[(DVec3, DVec3)],
    in_view: impl Iterator<Item = usize>,
) -> Vec<bool> {
    let n = view.pixels;
    let mut depth = vec![f32::INFINITY; n * n];
    rasterize_mesh(view, map, |i, d| depth[i] = depth[i].min(d as f32));
    in_view
        .map(|i| {
            let (lo, hi) = boxes[i];
            let probe = merge(&[WorldBox {
                lo: lo.to_array(),
                hi: hi.to_array(),
            }]);
            let mut seen = false;
            for tri in probe.triangles_f64() {
                rasterize(view, &tri, |p, d| {
                    let row = p / n;
                    seen |= row >= first && row <= last && (d as f32) < depth[p];
                });
            }
            seen
        })
        .collect()
}
