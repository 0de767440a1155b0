//! Open meshes (holes, open bottoms, gaps between parts) can show their inside. Whatever a camera
//! that is not below the object sees through such an opening must stay empty: open-bottomed game
//! art is never seen from below, but it is seen from every other side.
//!
//! The test renders the original's depth from many directions above the horizon. Voxels with a
//! corner in front of that depth are removed before boxes grow, and each finished box is checked
//! face by face, so a box that slips through between voxel corners is still caught. Each pixel
//! takes the farthest depth of its 3×3 neighbourhood, so that an opening seen from a direction
//! between the sampled ones, or between pixel centres, still counts.
//!
//! A small hole lets a camera see in only from a narrow cone of directions, which can fall
//! between the sampled ones. So cameras are also placed in the openings themselves (a connected
//! run of boundary edges), looking in: whatever shows through an opening from outside is seen
//! from some point of it, near enough. An outside camera not below a point sees it through the
//! opening only past a point of the opening at least as high, so these cameras count only what
//! lies no higher than the opening's highest point.

pub mod gpu;

use crate::geom::camera::{View, fibonacci_sphere};
use crate::geom::raster::{depth_images, rasterize};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::{BoundaryEdge, Mesh};
use crate::voxel::Grid;
use crate::voxel::winding::WindingField;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

/// Directions on the whole sphere; those not below the object are used.
const DIRECTIONS: usize = 256;
const PIXELS: usize = 256;

/// Pixels per side of the tiles whose farthest depth gives a quick "hidden" answer (TILE in
/// shaders/exposure.wgsl).
pub(crate) const TILE: usize = 8;
const R: usize = 1;

/// Cameras in one opening: at its centre and at points of its rim spread farthest apart.
const EYES_PER_OPENING: usize = 3;
/// How near a half the winding number at a point of an opening is when nothing fills it.
const OPEN_WINDING: f64 = 0.3;
/// Cameras in all openings, the largest openings first: each renders five or six faces of a
/// cube map.
const MAX_EYES: usize = 24;

pub struct OpenViews {
    /// The orthographic views from directions above the horizon, then the cameras in the
    /// openings.
    views: Vec<View>,
    /// How many of `views` are orthographic.
    sky_views: usize,
    /// Per camera in an opening, the height of the highest point of its opening (or its own,
    /// if higher): it counts only what lies no higher.
    horizons: Vec<f64>,
    /// Per view, each pixel's farthest depth over its neighbourhood, one image after another.
    depths: Vec<f32>,
    /// Per view, the farthest depth of each TILE × TILE tile of `depths`.
    tiles: Vec<f32>,
}

impl OpenViews {
    /// Renders the views' depth images, the orthographic ones on `gpu` when given
    /// (shaders/raster.wgsl). `boundary` is the mesh's open boundary.
    pub fn new(mesh: &Mesh, boundary: &[BoundaryEdge], gpu: Option<&Gpu>) -> Result<OpenViews, GpuError> {
        let (center, radius) = mesh.bounding_sphere();
        let mut views: Vec<View> = fibonacci_sphere(DIRECTIONS)
            .into_iter()
            .filter(|d| d.y >= 0.0)
            .map(|d| View::new(d, center, radius, PIXELS))
            .collect();
        let sky_views = views.len();
        let eyes = opening_eyes(mesh, boundary);
        let mut horizons = Vec::new();
        for (eye, horizon) in eyes {
            // The face looking up sees only what is higher than the camera: it counts only
            // where the opening reaches higher still.
            for view in View::cube_map(eye, PIXELS, 2e-4 * radius)
                .into_iter()
                .filter(|v| v.dir.y > -0.5 || horizon > eye.y)
            {
                views.push(view);
                horizons.push(horizon);
            }
        }
        // The GPU rasterizer draws orthographic views only; the CPU draws the cameras in the
        // openings meanwhile.
        let (sky, eyes) = views.split_at(sky_views);
        let (sky_images, eye_images) = rayon::join(|| depth_images(sky, mesh, gpu), || depth_images(eyes, mesh, None));
        let mut images = sky_images?;
        images.extend(eye_images?);
        // One after another, as the GPU takes them.
        let mut depths = vec![0f32; images.len() * PIXELS * PIXELS];
        depths
            .par_chunks_mut(PIXELS * PIXELS)
            .zip(&images)
            .for_each(|(out, image)| farthest_nearby(image, PIXELS, out));
        let mut tiles = vec![0f32; views.len() * (PIXELS / TILE).pow(2)];
        tiles
            .par_chunks_mut((PIXELS / TILE).pow(2))
            .zip(depths.par_chunks(PIXELS * PIXELS))
            .for_each(|(out, depth)| farthest_per_tile(depth, PIXELS, out));
        Ok(OpenViews {
            views,
            sky_views,
            horizons,
            depths,
            tiles,
        })
    }

    /// For a camera in an opening, the height up to which it counts what it sees.
    fn horizon(&self, view: usize) -> Option<f64> {
        view.checked_sub(self.sky_views).map(|e| self.horizons[e])
    }

    /// Whether view `view` sees point `p` in front of the original's surface.
    fn sees(&self, view: usize, p: DVec3) -> bool {
        let v = &self.views[view];
        let q = v.project(p);
        let n = v.pixels as f64;
        let off_image = !(q.x >= 0.0 && q.y >= 0.0 && q.x < n && q.y < n);
        match self.horizon(view) {
            // What the directions above the horizon do not frame lies outside the mesh.
            None if off_image => return true,
            // A camera in an opening sees only what lies in front of it, in its face, and no
            // higher than its opening.
            Some(horizon) if off_image || q.z <= v.depth_tolerance() || p.y > horizon => return false,
            _ => {}
        }
        let depth = self.depths[(view * PIXELS + q.y as usize) * PIXELS + q.x as usize];
        q.z < f64::from(depth) - v.depth_tolerance()
    }

    /// Clears the voxels of `inner` that a view sees at one of their corners, testing the
    /// corners on `gpu` when given (shaders/exposure.wgsl). Returns how many were cleared.
    /// `Unsupported` where the GPU cannot test them, with `inner` untouched.
    pub fn remove_exposed(&self, grid: &Grid, inner: &mut [bool], gpu: Option<&Gpu>) -> Result<usize, GpuError> {
        // Neighbouring voxels share corners: test each corner once.
        let [_, ny, nz] = grid.dims;
        let corner = |x: usize, y: usize, z: usize| (x * (ny + 1) + y) * (nz + 1) + z;
        let corners_of = |i: usize| {
            let [x, y, z] = grid.coords(i);
            (0..8).map(move |c| corner(x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1)))
        };
        // A corner is needed when one of the (up to 8) voxels around it is inner.
        let [nx, ny1, nz1] = [grid.dims[0], ny + 1, nz + 1];
        let needed: Vec<bool> = (0..(nx + 1) * ny1 * nz1)
            .into_par_iter()
            .map(|c| {
                let (x, y, z) = (c / (ny1 * nz1), (c / nz1) % ny1, c % nz1);
                let around = |v: usize, n: usize| v.saturating_sub(1)..v.min(n - 1) + 1;
                around(x, nx).any(|vx| around(y, ny).any(|vy| around(z, nz).any(|vz| inner[grid.index(vx, vy, vz)])))
            })
            .collect();
        // `Unsupported` on the GPU leaves `inner` as it was, for the caller to run this again
        // on the CPU.
        let seen = match gpu {
            Some(gpu) => self.seen_corners_on(gpu, grid, &needed)?,
            None => self.seen_corners(grid, &needed),
        };
        let exposed: Vec<usize> = (0..inner.len())
            .into_par_iter()
            .filter(|&i| inner[i] && corners_of(i).any(|c| seen[c]))
            .collect();
        for &i in &exposed {
            inner[i] = false;
        }
        Ok(exposed.len())
    }

    /// Of the `needed` grid corners (z fastest), those some view sees.
    fn seen_corners(&self, grid: &Grid, needed: &[bool]) -> Vec<bool> {
        let [_, ny, nz] = grid.dims;
        needed
            .par_iter()
            .enumerate()
            .map(|(c, &needed)| {
                let (x, y, z) = (c / ((ny + 1) * (nz + 1)), (c / (nz + 1)) % (ny + 1), c % (nz + 1));
                let p = grid.to_world(DVec3::new(x as f64, y as f64, z as f64));
                needed && (0..self.views.len()).any(|v| self.sees(v, p))
            })
            .collect()
    }

    /// [`OpenViews::seen_corners`] on the GPU.
    fn seen_corners_on(&self, gpu: &Gpu, grid: &Grid, needed: &[bool]) -> Result<Vec<bool>, GpuError> {
        // From points relative to the grid's origin to corners in voxel units.
        let size = grid.voxel_size;
        let to_corners = |r: [f64; 4]| [r[0] * size, r[1] * size, r[2] * size, r[3]].map(|v| v as f32);
        let mut rows = Vec::with_capacity(5 * self.views.len());
        for (v, view) in self.views.iter().enumerate() {
            let [x, y, w, mut depth] = view.projection_rows(grid.origin());
            // "In front of the depth by more than the tolerance", as one comparison.
            depth[3] += view.depth_tolerance();
            rows.extend([x, y, w, depth].map(to_corners));
            let limits = match self.horizon(v) {
                Some(horizon) => [(horizon - grid.origin().y) / size, 1.0, view.depth_tolerance(), 0.0],
                None => [f64::from(f32::MAX), 0.0, 0.0, 0.0],
            };
            rows.push(limits.map(|l| l as f32));
        }
        let words: Vec<[u32; 2]> = needed
            .par_chunks(32)
            .enumerate()
            .map(|(w, word)| [w as u32, word.iter().rev().fold(0, |bits, &n| bits << 1 | u32::from(n))])
            .filter(|&[_, bits]| bits != 0)
            .collect();
        let corner_dims = grid.dims.map(|d| d + 1);
        let seen = gpu::seen_corners(gpu, corner_dims, &words, &rows, &self.depths, &self.tiles, PIXELS)?;
        Ok((0..needed.len())
            .into_par_iter()
            .map(|c| seen[c / 32] & (1 << (c % 32)) != 0)
            .collect())
    }

    /// Whether no view sees any pixel of these triangles (a box, a quad) in front of the
    /// original. With `closed_convex` (a box), faces turned away from a view are skipped: the
    /// faces turned towards it cover them.
    pub fn hides(&self, triangles: &[[DVec3; 3]], closed_convex: bool) -> bool {
        (0..self.views.len()).all(|v| {
            let view = &self.views[v];
            // Cameras in openings are perspective: a face turned away from their axis may
            // still face them.
            let skip_turned_away = closed_convex && self.horizon(v).is_none();
            triangles
                .iter()
                .filter(|t| !skip_turned_away || (t[1] - t[0]).cross(t[2] - t[0]).dot(view.dir) > 0.0)
                .all(|t| self.hides_triangle(v, t))
        })
    }

    fn hides_triangle(&self, v: usize, triangle: &[DVec3; 3]) -> bool {
        let (view, depth) = (
            &self.views[v],
            &self.depths[v * PIXELS * PIXELS..(v + 1) * PIXELS * PIXELS],
        );
        let tolerance = view.depth_tolerance();
        if let Some(horizon) = self.horizon(v) {
            // Only what lies no higher than the opening counts.
            let mut hidden = true;
            rasterize(view, triangle, |i, d| {
                hidden &= d >= f64::from(depth[i]) - tolerance || view.unproject(i, d).y > horizon;
            });
            return hidden;
        }
        // Quick answer: the nearest corner lies behind the farthest depth of every tile under
        // the triangle's screen bounds.
        let corners = triangle.map(|p| view.project(p));
        let lo = corners[0].min(corners[1]).min(corners[2]);
        let hi = corners[0].max(corners[1]).max(corners[2]);
        let tiles = PIXELS / TILE;
        let range = |a: f64, b: f64| {
            let a = ((a - 0.5) / TILE as f64).floor().clamp(0.0, (tiles - 1) as f64) as usize;
            let b = ((b + 0.5) / TILE as f64).floor().clamp(0.0, (tiles - 1) as f64) as usize;
            a..=b
        };
        let farthest = range(lo.y, hi.y)
            .flat_map(|ty| range(lo.x, hi.x).map(move |tx| ty * tiles + tx))
            .map(|t| self.tiles[v * tiles * tiles + t])
            .fold(0f32, f32::max);
        let on_screen = lo.x >= 0.0 && lo.y >= 0.0 && hi.x <= PIXELS as f64 && hi.y <= PIXELS as f64;
        if on_screen && lo.z >= f64::from(farthest) - tolerance {
            return true;
        }
        let mut hidden = true;
        rasterize(view, triangle, |i, d| hidden &= d >= f64::from(depth[i]) - tolerance);
        hidden
    }
}

/// The farthest depth of each TILE × TILE tile, into `out` (zeroed).
fn farthest_per_tile(depth: &[f32], n: usize, out: &mut [f32]) {
    let tiles = n / TILE;
    for y in 0..n {
        for x in 0..n {
            let t = (y / TILE) * tiles + x / TILE;
            out[t] = out[t].max(depth[y * n + x]);
        }
    }
}

/// Each pixel's farthest depth over its 3×3 neighbourhood (infinite where any is empty), into
/// `out`.
fn farthest_nearby(depth: &[f32], n: usize, out: &mut [f32]) {
    for y in 0..n {
        for x in 0..n {
            let mut far = 0f32;
            for ny in y.saturating_sub(R)..=(y + R).min(n - 1) {
                for nx in x.saturating_sub(R)..=(x + R).min(n - 1) {
                    far = far.max(depth[ny * n + nx]);
                }
            }
            out[y * n + x] = far;
        }
    }
}

/// Where to place cameras in the mesh's openings (connected runs of boundary edges), at most
/// [`MAX_EYES`], the largest openings first. Each opening gives its centre and points of its rim
/// spread farthest apart, drawn a fifth of the way towards the centre. A point where the winding
/// number is near a half lies in a real gap and stays; any other is moved along the opening's
/// normal to the nearest point outside the solid, so that a camera where another part fills the
/// opening sees in only through a real gap. Each camera comes with the height it counts up to:
/// its opening's highest point, or its own where it moved higher. Cameras whose height is at the
/// very bottom of the mesh are left out: nothing lies lower for them to show.
fn opening_eyes(mesh: &Mesh, boundary: &[BoundaryEdge]) -> Vec<(DVec3, f64)> {
    let mut neighbours: HashMap<u32, Vec<&BoundaryEdge>> = HashMap::new();
    for e in boundary {
        neighbours.entry(e.a).or_default().push(e);
        neighbours.entry(e.b).or_default().push(e);
    }
    let mut starts: Vec<u32> = neighbours.keys().copied().collect();
    starts.sort_unstable();
    let position = |v: u32| mesh.positions[v as usize].as_dvec3();
    let mut visited = HashSet::new();
    let extent = |rim: &[DVec3]| {
        let (lo, hi) = crate::mesh::point_bounds(rim.iter().copied());
        (hi - lo).length()
    };
    // Each opening's rim points, vector area and extent.
    let mut openings: Vec<(Vec<DVec3>, DVec3, f64)> = Vec::new();
    for start in starts {
        let (mut stack, mut rim, mut area) = (vec![start], Vec::new(), DVec3::ZERO);
        while let Some(v) = stack.pop() {
            if visited.insert(v) {
                rim.push(position(v));
                for e in &neighbours[&v] {
                    stack.push(if e.a == v { e.b } else { e.a });
                    // Each edge is met from both ends: counted from its first.
                    if e.a == v {
                        area += position(e.a).cross(position(e.b)) * f64::from(e.weight) * 0.5;
                    }
                }
            }
        }
        if !rim.is_empty() {
            let size = extent(&rim);
            openings.push((rim, area, size));
        }
    }
    openings.sort_by(|a, b| b.2.total_cmp(&a.2));
    let (lo, hi) = mesh.bounds();
    let size = f64::from((hi - lo).length());
    let bottom = f64::from(lo.y) + 1e-3 * size;
    let field = WindingField::new(mesh, boundary);
    let mut eyes = Vec::new();
    for (rim, area, opening_size) in &openings {
        let centre = rim.iter().sum::<DVec3>() / rim.len() as f64;
        let mut chosen = vec![centre];
        while chosen.len() < EYES_PER_OPENING.min(rim.len() + 1) {
            let distance = |p: &DVec3| chosen.iter().map(|c| c.distance(*p)).fold(f64::INFINITY, f64::min);
            chosen.extend(rim.iter().max_by(|a, b| distance(a).total_cmp(&distance(b))).copied());
        }
        let normal = area.try_normalize().unwrap_or(DVec3::Y);
        let reach = opening_size.max(1e-3 * size);
        let in_gap = |p: DVec3| {
            if (field.winding(p) - 0.5).abs() < OPEN_WINDING {
                return Some(p);
            }
            // Steps of a sixteenth of the opening, both ways, nearest first.
            (1..=16)
                .flat_map(|k| [1.0, -1.0].map(|side| p + normal * (side * reach * k as f64 / 16.0)))
                .find(|&q| field.winding(q) < 0.5)
        };
        let points = chosen
            .iter()
            .enumerate()
            .map(|(k, &p)| if k == 0 { p } else { p + (centre - p) * 0.2 });
        let top = rim.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
        eyes.extend(
            points
                .filter_map(in_gap)
                .map(|p| (p, top.max(p.y)))
                .filter(|&(_, horizon)| horizon > bottom),
        );
        if eyes.len() >= MAX_EYES {
            eyes.truncate(MAX_EYES);
            break;
        }
    }
    eyes
}
