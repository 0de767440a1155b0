//! Coverage, false pixels and outside samples, as DESIGN.md defines them.

use crate::geom::camera::{View, fibonacci_sphere};
use crate::geom::proximity::SurfaceIndex;
use crate::geom::raster::{depth_images, draw_depth};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::{BoundaryEdge, Mesh};
use crate::voxel::winding::WindingField;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalSettings {
    /// Where the cameras are.
    pub view_set: ViewSet,
    /// View directions on a Fibonacci sphere, for the outside views.
    pub views: usize,
    /// Image width and height in pixels.
    pub pixels: usize,
    /// Points sampled on the occluder's surface for the outside test.
    pub outside_samples: usize,
}

impl EvalSettings {
    /// Whether [`evaluate`] draws these views on a GPU it is given: the outside views only;
    /// inside views are perspective, and the CPU draws them.
    pub fn draws_on_gpu(&self) -> bool {
        self.view_set == ViewSet::Outside
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ViewSet {
    /// Orthographic views from directions all around the mesh, framing its bounding sphere.
    Outside,
    /// A cube map (six 90° perspective views) from the centre of the mesh's bounds: what a
    /// player standing in a room sees of its walls.
    Inside,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Quality {
    /// Mean over views of |occluder ∩ original| / |original| pixels (views that see the
    /// original at all; 0 where none does).
    pub coverage: f64,
    pub coverage_min: f64,
    /// Views that see the original at all: coverage is theirs.
    pub views_seeing: usize,
    /// Pixels where the occluder would hide something visible, over all views.
    pub false_pixels: u64,
    /// The same over the views whose camera is not below the object (y up).
    pub false_pixels_non_below: u64,
    pub views: usize,
    pub views_non_below: usize,
    /// Share of points sampled on the occluder where the original's winding number is < 0.5,
    /// leaving out points on the original's surface (within 1e-4 of its size).
    pub outside_samples: f64,
    pub samples: usize,
    pub occluder_triangles: usize,
    /// The view direction (towards the camera) with the most false pixels, if any has some.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worst_view: Option<([f64; 3], u64)>,
}

/// The mean, 0 for none.
fn mean(values: &[f64]) -> f64 {
    match values.len() {
        0 => 0.0,
        n => values.iter().sum::<f64>() / n as f64,
    }
}

/// Judges `occluder` against `original`; `boundary` is the original's open boundary. With a
/// `gpu`, the outside views are rendered there (shaders/raster.wgsl); inside views, which are
/// perspective, always on the CPU.
pub fn evaluate(
    original: &Mesh,
    boundary: &[BoundaryEdge],
    occluder: &Mesh,
    settings: &EvalSettings,
    gpu: Option<&Gpu>,
) -> Result<Quality, GpuError> {
    let (center, radius) = original.bounding_sphere();
    let views: Vec<View> = match settings.view_set {
        ViewSet::Outside => {
            let extra = margin_pixels(occluder, center, radius, settings.pixels);
            fibonacci_sphere(settings.views)
                .into_iter()
                .map(|dir| View::new(dir, center, radius, settings.pixels).widened(extra))
                .collect()
        }
        ViewSet::Inside => {
            let (lo, hi) = original.bounds();
            View::cube_map(((lo + hi) * 0.5).as_dvec3(), settings.pixels, 2e-4 * radius)
        }
    };
    // Inside views are all from where a player stands; outside ones are "below" when the
    // camera is under the object.
    let inside = settings.view_set == ViewSet::Inside;
    let gpu = gpu.filter(|_| settings.draws_on_gpu());
    let judge = |view: &View, m: &[f32], o: &[f32]| {
        let tolerance = view.depth_tolerance() as f32;
        let (mut both, mut seen, mut false_pixels) = (0u64, 0u64, 0u64);
        for (dm, d_o) in m.iter().zip(o.iter()) {
            seen += u64::from(dm.is_finite());
            if d_o.is_finite() {
                if dm.is_finite() {
                    both += 1;
                }
                false_pixels += u64::from(!dm.is_finite() || *d_o < dm - tolerance);
            }
        }
        let coverage = (seen > 0).then(|| both as f64 / seen as f64);
        (coverage, false_pixels, inside || view.dir.y >= 0.0, view.dir)
    };
    let judge_on_cpu = |view: &View, m: &mut Vec<f32>, o: &mut Vec<f32>| {
        draw_depth(view, original, m);
        draw_depth(view, occluder, o);
        judge(view, m, o)
    };
    let per_view: Vec<(Option<f64>, u64, bool, DVec3)> = match gpu {
        Some(_) => {
            let images = |mesh: &Mesh| depth_images(&views, mesh, gpu);
            let (originals, occluders) = (images(original)?, images(occluder)?);
            // The GPU projects in f32, the CPU in f64: where the occluder shares an edge of the
            // silhouette, a pixel centre on it can fall inside the occluder alone (4 such pixels
            // on an H100 for a shell's own surface pieces). The CPU, the reference, judges
            // again each view the GPU finds a false pixel in.
            views
                .par_iter()
                .zip(originals.par_iter().zip(&occluders))
                .map(|(view, (m, o))| match judge(view, m, o) {
                    judged @ (_, 0, ..) => judged,
                    _ => judge_on_cpu(view, &mut Vec::new(), &mut Vec::new()),
                })
                .collect()
        }
        // A view at a time through two images a thread, not every view's images at once.
        None => views
            .par_iter()
            .map_init(|| (Vec::new(), Vec::new()), |(m, o), view| judge_on_cpu(view, m, o))
            .collect(),
    };
    let seen: Vec<f64> = per_view.iter().filter_map(|v| v.0).collect();
    let samples = sample_surface(occluder, settings.outside_samples);
    let field = WindingField::new(original, boundary);
    // A point on the original's surface (a patch) is on the solid's boundary, not outside it.
    let surface = SurfaceIndex::new(original, 2e-4 * radius);
    let outside = samples
        .par_iter()
        .filter(|&&p| field.winding(p) < 0.5 && !surface.on_surface(p))
        .count();
    Ok(Quality {
        coverage: mean(&seen),
        coverage_min: seen.iter().copied().reduce(f64::min).unwrap_or(0.0),
        views_seeing: seen.len(),
        false_pixels: per_view.iter().map(|v| v.1).sum(),
        false_pixels_non_below: per_view.iter().filter(|v| v.2).map(|v| v.1).sum(),
        views: per_view.len(),
        views_non_below: per_view.iter().filter(|v| v.2).count(),
        outside_samples: if samples.is_empty() {
            0.0
        } else {
            outside as f64 / samples.len() as f64
        },
        samples: samples.len(),
        occluder_triangles: occluder.triangles.len(),
        worst_view: per_view
            .iter()
            .filter(|v| v.1 > 0)
            .max_by_key(|v| v.1)
            .map(|v| (v.3.to_array(), v.1)),
    })
}

/// [`evaluate`] on `gpu` where it can draw the views, else on the CPU: the figures, and why the
/// CPU drew them when the GPU could not.
pub fn evaluate_where_it_can(
    original: &Mesh,
    boundary: &[BoundaryEdge],
    occluder: &Mesh,
    settings: &EvalSettings,
    gpu: Option<&Gpu>,
) -> Result<(Quality, Option<String>), GpuError> {
    match evaluate(original, boundary, occluder, settings, gpu) {
        Err(GpuError::Unsupported(why)) => Ok((evaluate(original, boundary, occluder, settings, None)?, Some(why))),
        judged => Ok((judged?, None)),
    }
}

/// Most pixels added on each side of an outside view for an occluder that reaches past the
/// original's frame, as a share of the view's size: the frame at most doubles, so the images at
/// most take four times the memory. Farther out, an occluder is already plainly wrong.
const MAX_MARGIN: f64 = 0.5;

/// Pixels to add on each side of an outside view framing the sphere (`center`, `radius`) in
/// `pixels`, so that the frame holds `occluder` too at the same scale: what sticks out sideways
/// is judged like the rest.
fn margin_pixels(occluder: &Mesh, center: DVec3, radius: f64, pixels: usize) -> usize {
    let reach = occluder
        .positions
        .iter()
        .map(|p| p.as_dvec3().distance(center))
        .fold(0.0, f64::max);
    let per_unit = pixels as f64 / (2.0 * radius.max(1e-12));
    let extra = ((reach - radius) * per_unit).ceil();
    if extra.is_nan() || extra <= 0.0 {
        return 0;
    }
    extra.min(MAX_MARGIN * pixels as f64) as usize
}

/// `n` points spread over the mesh's surface by area, from a fixed seed.
fn sample_surface(mesh: &Mesh, n: usize) -> Vec<DVec3> {
    let areas: Vec<f64> = mesh
        .triangles_f64()
        .map(|[a, b, c]| (b - a).cross(c - a).length() * 0.5)
        .scan(0.0, |sum, a| {
            *sum += a;
            Some(*sum)
        })
        .collect();
    let Some(&total) = areas.last() else {
        return Vec::new();
    };
    let mut rng = fastrand::Rng::with_seed(0x5eed);
    (0..n)
        .map(|_| {
            let t = areas.partition_point(|&c| c < rng.f64() * total).min(areas.len() - 1);
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let (mut u, mut v) = (rng.f64(), rng.f64());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            a + (b - a) * u + (c - a) * v
        })
        .collect()
}
