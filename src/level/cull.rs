//! The culling test of a level occluder, as a runtime would use it: from cameras inside the
//! level, the occluders go into a low-resolution depth buffer and every instance's bounding box
//! is tested against it. Ground truth renders the real meshes at 512 pixels: an instance is
//! visible if any of its pixels survive.
//!
//! Ground truth renders on the GPU when given one (shaders/cull.wgsl), else on the CPU.
//!
//! Cameras: a seeded random point in the level's bounds (shrunk by a tenth on each side), at a
//! random height in the lower half, looking in a random horizontal direction with a 90° field
//! of view. A point inside an instance's solid, where no player stands, is drawn again (in the
//! whole bounds where the lower half is all solid).

pub mod gpu;
pub mod probes;

use super::{Level, MeshRef};
use crate::eval::preview::brightness;
use crate::geom::camera::View;
use crate::geom::raster::covered::Occluder;
use crate::geom::raster::rasterize;
use crate::gpu::Gpu;
use crate::mesh::BoundaryEdge;
use crate::mesh::topology::orient_closed_components;
use crate::mesh::{IngestLimits, Mesh, load_file, point_bounds};
use crate::voxel::winding::WindingField;
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
    /// Camera positions drawn inside an instance's solid, where no player stands, and drawn
    /// again.
    pub cameras_in_solids: usize,
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
    /// Each camera and what it culled, for pictures.
    #[serde(skip)]
    pub shots: Vec<Shot>,
}

/// One camera of a cull test: where it stands, where it looks, and the instances the occluder
/// culled there, those among them visible in truth apart.
#[derive(Debug)]
pub struct Shot {
    pub eye: DVec3,
    pub forward: DVec3,
    pub culled: Vec<usize>,
    pub wrongly_culled: Vec<usize>,
}

impl Shot {
    /// The camera as the test renders its ground truth, at `pixels` wide; `near` as the test's.
    pub fn view(&self, pixels: usize, near: f64) -> View {
        View::perspective(self.eye, -self.forward, pixels, near)
    }
}

/// The near plane of a level's cameras: far closer than its depth tolerance, so that a wall next
/// to the eye is not clipped away.
pub fn near_plane(boxes: &[(DVec3, DVec3)]) -> f64 {
    let (lo, hi) = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
    depth_tolerance(lo, hi) * 1e-3
}

fn depth_tolerance(lo: DVec3, hi: DVec3) -> f64 {
    1e-4 * (hi - lo).length()
}

/// Runs `cameras` cameras over `level`, whose unique meshes are `meshes`, with `occluder` at
/// `pixels` wide, rendering the ground truth on `gpu` when given.
pub fn cull_eval(
    level: &Level,
    meshes: &HashMap<&MeshRef, Mesh>,
    occluder: &Mesh,
    cameras: usize,
    pixels: usize,
    gpu: Option<&Gpu>,
) -> Result<CullReport, String> {
    let boxes = instance_bounds(level, meshes);
    let (lo, hi) = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
    let tolerance = depth_tolerance(lo, hi);
    let (poses, cameras_in_solids) = free_camera_poses(level, meshes, &boxes, (lo, hi), cameras)?;
    let near = near_plane(&boxes);
    let truth_view = |(eye, forward): (DVec3, DVec3)| View::perspective(eye, -forward, TRUTH_PIXELS, near);
    // The GPU renders one camera after another; the CPU renders them in parallel below.
    let truth_views: Vec<View> = poses.iter().map(|&pose| truth_view(pose)).collect();
    let gpu_truth = match gpu {
        Some(gpu) => Some(gpu_ground_truth(gpu, level, meshes, &boxes, &truth_views, near).map_err(|e| e.to_string())?),
        None => None,
    };
    // Depth over the pixels the occluder covers whole: a pixel whose centre it covers may still
    // be partly open (a doorway narrower than a pixel).
    let covered = Occluder::new(occluder);
    let shots: Vec<(usize, Shot)> = poses
        .par_iter()
        .enumerate()
        .map(|(c, &(eye, forward))| {
            let coarse = View::perspective(eye, -forward, pixels, near);
            let occluded = covered.depth(&coarse);
            let visible = match &gpu_truth {
                Some(images) => images[c].clone(),
                None => ground_truth(&truth_views[c], level, meshes, &boxes),
            };
            let mut in_view = 0;
            let mut shot = Shot {
                eye,
                forward,
                culled: Vec::new(),
                wrongly_culled: Vec::new(),
            };
            for (i, b) in boxes.iter().enumerate() {
                let Some(test) = box_on_screen(&coarse, b) else {
                    continue;
                };
                in_view += 1;
                if fully_behind(&occluded, pixels, &test, tolerance) {
                    shot.culled.push(i);
                    if visible[i] {
                        shot.wrongly_culled.push(i);
                    }
                }
            }
            (in_view, shot)
        })
        .collect();
    let shares: Vec<f64> = shots
        .iter()
        .filter(|(in_view, _)| *in_view > 0)
        .map(|(in_view, shot)| shot.culled.len() as f64 / *in_view as f64)
        .collect();
    let worst = shots
        .iter()
        .map(|(_, shot)| shot)
        .filter(|shot| !shot.wrongly_culled.is_empty())
        .max_by_key(|shot| shot.wrongly_culled.len())
        .map(|shot| (shot.eye.to_array(), shot.forward.to_array(), shot.wrongly_culled.len()));
    Ok(CullReport {
        cameras,
        cameras_in_solids,
        instances: level.instances.len(),
        culled_share: shares.iter().sum::<f64>() / shares.len().max(1) as f64,
        wrongly_culled: shots.iter().map(|(_, shot)| shot.wrongly_culled.len()).sum(),
        worst_camera: worst,
        occluder_pixels: pixels,
        occluder_triangles: occluder.triangles.len(),
        truth_device: gpu.map_or("cpu".into(), Gpu::name),
        shots: shots.into_iter().map(|(_, shot)| shot).collect(),
    })
}

/// Every unique mesh the level places, read once: files from disk, parts from the level, and
/// keys from `keyed` (meshes fetched by whoever holds the store).
pub fn load_meshes<'a>(level: &'a Level, keyed: &HashMap<String, Mesh>) -> Result<HashMap<&'a MeshRef, Mesh>, String> {
    let mut meshes: HashMap<&MeshRef, Mesh> = HashMap::new();
    for (m, _) in &level.instances {
        if meshes.contains_key(m) {
            continue;
        }
        let mesh = match m {
            MeshRef::File(path) => {
                let read = load_file(path, &IngestLimits::default());
                read.map_err(|e| format!("{}: {e}", path.display()))?.0
            }
            MeshRef::Part(p) => level.parts[*p].1.clone(),
            MeshRef::Key(k) => keyed
                .get(k)
                .cloned()
                .ok_or_else(|| format!("mesh {k} is only a key: cull-eval needs the real meshes"))?,
        };
        meshes.insert(m, mesh);
    }
    Ok(meshes)
}

/// Every instance placed, as one mesh: the map's own triangles.
pub fn placed_map(level: &Level, meshes: &HashMap<&MeshRef, Mesh>) -> Mesh {
    let mut map = Mesh::default();
    for (m, matrix) in &level.instances {
        let mesh = &meshes[m];
        map.append(&Mesh {
            positions: placed_positions(mesh, matrix).map(|p| p.as_vec3()).collect(),
            triangles: mesh.triangles.clone(),
        });
    }
    map
}

/// Each instance's bounds, placed.
pub fn instance_bounds(level: &Level, meshes: &HashMap<&MeshRef, Mesh>) -> Vec<(DVec3, DVec3)> {
    level
        .instances
        .iter()
        .map(|(m, matrix)| point_bounds(placed_positions(&meshes[m], matrix)))
        .collect()
}

fn placed_positions<'a>(mesh: &'a Mesh, matrix: &'a DMat4) -> impl Iterator<Item = DVec3> + 'a {
    mesh.positions.iter().map(|p| matrix.transform_point3(p.as_dvec3()))
}

/// Candidate camera positions drawn per camera before the level counts as having no free space.
const DRAWS_PER_CAMERA: usize = 100;

/// Seeded random cameras (eye, horizontal forward direction) within the level's bounds, each
/// standing in free space, where a player could be: inside no instance's solid (its winding
/// number there under a half). Also returns how many positions were drawn inside a solid.
fn free_camera_poses(
    level: &Level,
    meshes: &HashMap<&MeshRef, Mesh>,
    boxes: &[(DVec3, DVec3)],
    (lo, hi): (DVec3, DVec3),
    cameras: usize,
) -> Result<(Vec<(DVec3, DVec3)>, usize), String> {
    let solids: HashMap<&MeshRef, (Mesh, Vec<BoundaryEdge>)> = meshes
        .iter()
        .map(|(&m, mesh)| {
            let mut mesh = mesh.clone();
            let boundary = orient_closed_components(&mut mesh).boundary;
            (m, (mesh, boundary))
        })
        .collect();
    let fields: HashMap<&MeshRef, WindingField> = solids
        .iter()
        .map(|(&m, (mesh, boundary))| (m, WindingField::new(mesh, boundary)))
        .collect();
    let inverses: Vec<DMat4> = level.instances.iter().map(|(_, matrix)| matrix.inverse()).collect();
    let in_a_solid = |eye: DVec3| {
        boxes.iter().enumerate().any(|(i, (b_lo, b_hi))| {
            eye.cmpge(*b_lo).all()
                && eye.cmple(*b_hi).all()
                && fields[&level.instances[i].0].winding(inverses[i].transform_point3(eye)) >= 0.5
        })
    };
    // Where players stand: the lower half of the bounds, shrunk by a tenth on each side; where
    // that is all solid (a level of stacked blocks), anywhere in the bounds.
    let size = hi - lo;
    let regions = [
        (
            lo + size * DVec3::new(0.1, 0.05, 0.1),
            size * DVec3::new(0.8, 0.45, 0.8),
        ),
        (lo, size),
    ];
    let mut rng = fastrand::Rng::with_seed(0xc0ffee);
    let (mut poses, mut refused) = (Vec::with_capacity(cameras), 0);
    for (corner, extent) in regions {
        let mut draws = 0;
        while poses.len() < cameras && draws < DRAWS_PER_CAMERA * cameras {
            draws += 1;
            let eye = corner + extent * DVec3::new(rng.f64(), rng.f64(), rng.f64());
            let yaw = rng.f64() * std::f64::consts::TAU;
            if in_a_solid(eye) {
                refused += 1;
            } else {
                poses.push((eye, DVec3::new(yaw.cos(), 0.0, yaw.sin())));
            }
        }
    }
    if poses.len() < cameras {
        return Err(format!(
            "no free space for cameras: {refused} positions drawn in the level's bounds all lie inside solids"
        ));
    }
    Ok((poses, refused))
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

/// A bounding box's screen rectangle (pixels, inclusive, clamped) and nearest depth; None when
/// it is wholly off screen or behind the camera.
struct ScreenBox {
    x: [usize; 2],
    y: [usize; 2],
    near: f64,
}

fn box_on_screen(view: &View, (lo, hi): &(DVec3, DVec3)) -> Option<ScreenBox> {
    let n = view.pixels as f64;
    let near = view.depth_tolerance();
    let corner = |c: usize| {
        DVec3::new(
            if c & 1 == 0 { lo.x } else { hi.x },
            if c & 2 == 0 { lo.y } else { hi.y },
            if c & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let depth = |p: DVec3| view.project(p).z;
    // The box cut by the near plane: its corners in front of it, and where its edges cross it.
    // A box reaching behind the camera thus spreads to the screen's edges, nearest at the plane.
    let mut points: Vec<DVec3> = (0..8).map(corner).filter(|&p| depth(p) >= near).collect();
    for c in 0..8 {
        for axis in [1, 2, 4] {
            let (p, q) = (corner(c), corner(c | axis));
            let (zp, zq) = (depth(p), depth(q));
            if c & axis == 0 && (zp >= near) != (zq >= near) {
                points.push(p + (q - p) * ((near - zp) / (zq - zp)));
            }
        }
    }
    if points.is_empty() {
        return None;
    }
    let corners: Vec<DVec3> = points.iter().map(|&p| view.project(p)).collect();
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

/// What a view of the placed meshes shows per pixel, rows from the bottom: the nearest depth,
/// the instance there (u32::MAX for none) and its light (0 to 1, facing the camera brightest).
pub struct Frame {
    pub depth: Vec<f32>,
    pub instance: Vec<u32>,
    pub light: Vec<f32>,
}

/// Renders the real meshes of `instances` front to back, skipping those whose box is already
/// wholly behind what is drawn (then none of their pixels could survive).
pub fn render_instances(
    view: &View,
    level: &Level,
    meshes: &HashMap<&MeshRef, Mesh>,
    boxes: &[(DVec3, DVec3)],
    instances: &[usize],
) -> Frame {
    let n = view.pixels;
    let mut order: Vec<(usize, ScreenBox)> = instances
        .iter()
        .filter_map(|&i| box_on_screen(view, &boxes[i]).map(|s| (i, s)))
        .collect();
    order.sort_by(|a, b| a.1.near.total_cmp(&b.1.near));
    let mut frame = Frame {
        depth: vec![f32::INFINITY; n * n],
        instance: vec![u32::MAX; n * n],
        light: vec![0.0; n * n],
    };
    for (i, screen) in &order {
        if fully_behind(&frame.depth, n, screen, 0.0) {
            continue;
        }
        let (m, matrix): &(MeshRef, DMat4) = &level.instances[*i];
        let mesh = &meshes[m];
        let placed: Vec<DVec3> = placed_positions(mesh, matrix).collect();
        for t in &mesh.triangles {
            let tri = t.map(|v| placed[v as usize]);
            let mut lit = None;
            rasterize(view, &tri, |p, d| {
                if (d as f32) < frame.depth[p] {
                    frame.depth[p] = d as f32;
                    frame.instance[p] = *i as u32;
                    // Lit by the direction to the camera at the triangle, found once it shows.
                    frame.light[p] = *lit.get_or_insert_with(|| brightness(view, &tri) as f32);
                }
            });
        }
    }
    frame
}

/// Which instances show at least one pixel.
fn ground_truth(view: &View, level: &Level, meshes: &HashMap<&MeshRef, Mesh>, boxes: &[(DVec3, DVec3)]) -> Vec<bool> {
    let all: Vec<usize> = (0..boxes.len()).collect();
    let frame = render_instances(view, level, meshes, boxes, &all);
    let mut visible = vec![false; boxes.len()];
    for &i in frame.instance.iter().filter(|&&i| i != u32::MAX) {
        visible[i as usize] = true;
    }
    visible
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluder::{WorldBox, merge::merge};

    #[test]
    fn cameras_stand_outside_the_solids() {
        // A block filling most of the level, and a small one off its corner that widens the
        // level's bounds: most positions drawn fall inside the block.
        let block = merge(&[WorldBox {
            lo: [0.0; 3],
            hi: [8.0, 10.0, 8.0],
        }]);
        let corner = DMat4::from_translation(DVec3::new(9.0, 0.0, 9.0)) * DMat4::from_scale(DVec3::splat(0.1));
        let level = Level {
            name: "blocks".into(),
            instances: vec![(MeshRef::Part(0), DMat4::IDENTITY), (MeshRef::Part(0), corner)],
            parts: vec![("block".into(), block, Default::default())],
        };
        let meshes = load_meshes(&level, &HashMap::new()).expect("parts load");
        let boxes = instance_bounds(&level, &meshes);
        let bounds = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
        let (poses, refused) = free_camera_poses(&level, &meshes, &boxes, bounds, 50).expect("free space exists");
        assert_eq!(poses.len(), 50);
        assert!(refused > 50, "{refused} drawn inside the block");
        for (eye, _) in poses {
            assert!(eye.x > 8.0 || eye.z > 8.0, "a camera inside the block at {eye}");
        }
    }
}
