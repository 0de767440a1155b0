//! The culling test of a level occluder, as a runtime would use it: from cameras inside the
//! level, the occluders go into a low-resolution depth buffer and every instance's bounding box
//! is tested against it. Ground truth renders the real meshes at 512 pixels: an instance is
//! visible if any of its pixels survive.
//!
//! Ground truth renders on the GPU when given one (shaders/cull.wgsl), else on the CPU.
//!
//! Cameras: a seeded random point in the level's bounds (shrunk by a tenth on each side), at a
//! random height in the lower half, looking in a random horizontal direction with a 90° field
//! of view.

pub mod gpu;

use super::{Level, MeshRef};
use crate::geom::camera::View;
use crate::geom::raster::{rasterize, rasterize_inner};
use crate::gpu::Gpu;
use crate::mesh::{Mesh, load_file, point_bounds};
use glam::{DMat4, DVec3};
use gpu::InstanceScene;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashMap;

/// Ground-truth image width.
const TRUTH_PIXELS: usize = 512;

#[derive(Debug, Serialize)]
pub struct CullReport {
    pub cameras: usize,
    pub instances: usize,
    /// Mean over cameras of occlusion-culled / in-view instances.
    pub culled_share: f64,
    /// Instances culled while visible, over all cameras: must be 0.
    pub wrongly_culled: usize,
    /// The camera with the most wrongly culled instances, if any: (position, direction, count).
    pub worst_camera: Option<([f64; 3], [f64; 3], usize)>,
    pub occluder_pixels: usize,
    pub occluder_triangles: usize,
    /// What rendered the ground truth: "cpu", or the GPU adapter's name.
    pub truth_device: String,
}

/// Runs `cameras` cameras over `level` with `occluder` at `pixels` wide, rendering the ground
/// truth on `gpu` when given.
pub fn cull_eval(
    level: &Level,
    occluder: &Mesh,
    cameras: usize,
    pixels: usize,
    gpu: Option<&Gpu>,
) -> Result<CullReport, String> {
    let meshes = load_meshes(level)?;
    let boxes: Vec<(DVec3, DVec3)> = level
        .instances
        .iter()
        .map(|(m, matrix)| point_bounds(placed_positions(&meshes[m], matrix)))
        .collect();
    let (lo, hi) = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
    let tolerance = 1e-4 * (hi - lo).length();
    let poses = camera_poses(lo, hi, cameras);
    // Views look along -dir. Their near plane sits far closer than the depth tolerance, so
    // that a wall next to the eye is not clipped away.
    let near = tolerance * 1e-3;
    let truth_view = |(eye, forward): (DVec3, DVec3)| View::perspective(eye, -forward, TRUTH_PIXELS, near);
    // The GPU renders one camera after another; the CPU renders them in parallel below.
    let truth_views: Vec<View> = poses.iter().map(|&pose| truth_view(pose)).collect();
    let gpu_truth = match gpu {
        Some(gpu) => {
            Some(gpu_ground_truth(gpu, level, &meshes, &boxes, &truth_views, near).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    let results: Vec<(usize, usize, usize)> = poses
        .par_iter()
        .enumerate()
        .map(|(c, &(eye, forward))| {
            let coarse = View::perspective(eye, -forward, pixels, near);
            let occluded = occluder_depth(&coarse, occluder);
            let visible = match &gpu_truth {
                Some(images) => images[c].clone(),
                None => ground_truth(&truth_views[c], level, &meshes, &boxes),
            };
            let (mut in_view, mut culled, mut wrong) = (0, 0, 0);
            for (i, b) in boxes.iter().enumerate() {
                let Some(test) = box_on_screen(&coarse, b) else {
                    continue;
                };
                in_view += 1;
                if fully_behind(&occluded, pixels, &test, tolerance) {
                    culled += 1;
                    wrong += usize::from(visible[i]);
                }
            }
            (in_view, culled, wrong)
        })
        .collect();
    let shares: Vec<f64> = results
        .iter()
        .filter(|r| r.0 > 0)
        .map(|r| r.1 as f64 / r.0 as f64)
        .collect();
    let worst = results
        .iter()
        .enumerate()
        .filter(|(_, r)| r.2 > 0)
        .max_by_key(|(_, r)| r.2)
        .map(|(c, r)| (poses[c].0.to_array(), poses[c].1.to_array(), r.2));
    Ok(CullReport {
        cameras,
        instances: level.instances.len(),
        culled_share: shares.iter().sum::<f64>() / shares.len().max(1) as f64,
        wrongly_culled: results.iter().map(|r| r.2).sum(),
        worst_camera: worst,
        occluder_pixels: pixels,
        occluder_triangles: occluder.triangles.len(),
        truth_device: gpu.map_or("cpu".into(), Gpu::name),
    })
}

/// Every unique mesh the level places, read once.
fn load_meshes(level: &Level) -> Result<HashMap<&MeshRef, Mesh>, String> {
    let mut meshes: HashMap<&MeshRef, Mesh> = HashMap::new();
    for (m, _) in &level.instances {
        if meshes.contains_key(m) {
            continue;
        }
        let mesh = match m {
            MeshRef::File(path) => load_file(path).map_err(|e| format!("{}: {e}", path.display()))?.0,
            MeshRef::Part(p) => level.parts[*p].1.clone(),
            MeshRef::Key(k) => return Err(format!("mesh {k} is only a key: cull-eval needs the real meshes")),
        };
        meshes.insert(m, mesh);
    }
    Ok(meshes)
}

fn placed_positions<'a>(mesh: &'a Mesh, matrix: &'a DMat4) -> impl Iterator<Item = DVec3> + 'a {
    mesh.positions.iter().map(|p| matrix.transform_point3(p.as_dvec3()))
}

/// Seeded random cameras (eye, horizontal forward direction) within the level's bounds.
fn camera_poses(lo: DVec3, hi: DVec3, cameras: usize) -> Vec<(DVec3, DVec3)> {
    let size = hi - lo;
    let mut rng = fastrand::Rng::with_seed(0xc0ffee);
    (0..cameras)
        .map(|_| {
            let eye = DVec3::new(
                lo.x + size.x * (0.1 + 0.8 * rng.f64()),
                lo.y + size.y * (0.05 + 0.45 * rng.f64()),
                lo.z + size.z * (0.1 + 0.8 * rng.f64()),
            );
            let yaw = rng.f64() * std::f64::consts::TAU;
            (eye, DVec3::new(yaw.cos(), 0.0, yaw.sin()))
        })
        .collect()
}

/// The ground truth of every view on the GPU: which instances show at least one pixel.
fn gpu_ground_truth(
    gpu: &Gpu,
    level: &Level,
    meshes: &HashMap<&MeshRef, Mesh>,
    boxes: &[(DVec3, DVec3)],
    views: &[View],
    near: f64,
) -> Result<Vec<Vec<bool>>, crate::gpu::GpuError> {
    let placed: Vec<(Vec<DVec3>, &[[u32; 3]])> = level
        .instances
        .iter()
        .map(|(m, matrix)| {
            let mesh = &meshes[m];
            (placed_positions(mesh, matrix).collect(), &mesh.triangles[..])
        })
        .collect();
    let scene = InstanceScene::new(gpu, &placed, TRUTH_PIXELS as u32);
    views
        .iter()
        .map(|view| {
            let in_view: Vec<usize> = (0..boxes.len())
                .filter(|&i| box_on_screen(view, &boxes[i]).is_some())
                .collect();
            scene.visible(view, near, &in_view)
        })
        .collect()
}

/// The occluders' depth over the pixels they cover whole, each at its farthest: a pixel whose
/// centre an occluder covers may still be partly open (a doorway narrower than a pixel).
fn occluder_depth(view: &View, occluder: &Mesh) -> Vec<f32> {
    let n = view.pixels;
    let mut depth = vec![f32::INFINITY; n * n];
    for tri in occluder.triangles_f64() {
        rasterize_inner(view, &tri, |i, d| depth[i] = depth[i].min(d as f32));
    }
    depth
}

/// A bounding box's screen rectangle (pixels, inclusive, clamped) and nearest depth; None when
/// it is wholly off screen. A box reaching behind the camera covers the whole screen at depth 0.
struct ScreenBox {
    x: [usize; 2],
    y: [usize; 2],
    near: f64,
}

fn box_on_screen(view: &View, (lo, hi): &(DVec3, DVec3)) -> Option<ScreenBox> {
    let n = view.pixels as f64;
    let corners: Vec<DVec3> = (0..8)
        .map(|c| {
            let p = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            view.project(p)
        })
        .collect();
    if corners.iter().any(|c| c.z <= view.depth_tolerance()) {
        // Straddles the camera plane: treat as filling the screen, nearest at the eye. It can
        // still be outside the frustum, but it is never culled.
        return Some(ScreenBox {
            x: [0, view.pixels - 1],
            y: [0, view.pixels - 1],
            near: 0.0,
        });
    }
    let (a, b) = point_bounds(corners.iter().copied());
    if b.x < 0.0 || b.y < 0.0 || a.x > n || a.y > n {
        return None;
    }
    let clamp = |v: f64| (v.max(0.0).min(n - 1.0)) as usize;
    Some(ScreenBox {
        x: [clamp(a.x - 1.0), clamp(b.x + 1.0)],
        y: [clamp(a.y - 1.0), clamp(b.y + 1.0)],
        near: a.z,
    })
}

/// Whether every pixel under the rectangle holds an occluder nearer than the box.
fn fully_behind(depth: &[f32], n: usize, b: &ScreenBox, tolerance: f64) -> bool {
    (b.y[0]..=b.y[1]).all(|y| (b.x[0]..=b.x[1]).all(|x| f64::from(depth[y * n + x]) < b.near - tolerance))
}

/// Which instances show at least one pixel, rendering the real meshes front to back and
/// skipping those whose box is already wholly behind what is drawn (then none of their pixels
/// could survive).
fn ground_truth(view: &View, level: &Level, meshes: &HashMap<&MeshRef, Mesh>, boxes: &[(DVec3, DVec3)]) -> Vec<bool> {
    let n = view.pixels;
    let mut order: Vec<(usize, ScreenBox)> = boxes
        .iter()
        .enumerate()
        .filter_map(|(i, b)| box_on_screen(view, b).map(|s| (i, s)))
        .collect();
    order.sort_by(|a, b| a.1.near.total_cmp(&b.1.near));
    let mut depth = vec![f32::INFINITY; n * n];
    let mut id = vec![u32::MAX; n * n];
    for (i, screen) in &order {
        if fully_behind(&depth, n, screen, 0.0) {
            continue;
        }
        let (m, matrix): &(MeshRef, DMat4) = &level.instances[*i];
        let mesh = &meshes[m];
        let placed: Vec<DVec3> = placed_positions(mesh, matrix).collect();
        for t in &mesh.triangles {
            let tri = t.map(|v| placed[v as usize]);
            rasterize(view, &tri, |p, d| {
                if (d as f32) < depth[p] {
                    depth[p] = d as f32;
                    id[p] = *i as u32;
                }
            });
        }
    }
    let mut visible = vec![false; boxes.len()];
    for &i in id.iter().filter(|&&i| i != u32::MAX) {
        visible[i as usize] = true;
    }
    visible
}
