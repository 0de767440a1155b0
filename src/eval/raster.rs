//! Software rasterization at pixel centres: depth images of meshes and coverage masks of boxes,
//! through orthographic cameras around a mesh or perspective cameras inside it.

use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug)]
enum Lens {
    /// Framing the sphere (center, radius).
    Orthographic { center: DVec3, radius: f64 },
    /// A 90° field of view from `eye`.
    Perspective { eye: DVec3 },
}

/// A square camera of `pixels` × `pixels`.
#[derive(Clone, Debug)]
pub struct View {
    /// Unit vector from what is seen towards the camera.
    pub dir: DVec3,
    right: DVec3,
    up: DVec3,
    lens: Lens,
    pub pixels: usize,
    tolerance: f64,
}

impl View {
    /// An orthographic camera framing a bounding sphere, looking along `-dir`.
    pub fn new(dir: DVec3, center: DVec3, radius: f64, pixels: usize) -> View {
        let radius = radius.max(1e-12);
        let lens = Lens::Orthographic { center, radius };
        View::looking(dir, lens, pixels, 2e-4 * radius)
    }

    /// A perspective camera at `eye` with a 90° field of view, looking along `-dir`.
    /// `tolerance` is the depth tolerance of "nearer than" tests.
    pub fn perspective(eye: DVec3, dir: DVec3, pixels: usize, tolerance: f64) -> View {
        View::looking(dir, Lens::Perspective { eye }, pixels, tolerance)
    }

    /// The six faces of a cube map around `eye`.
    pub fn cube_map(eye: DVec3, pixels: usize, tolerance: f64) -> Vec<View> {
        [DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y, DVec3::Z, DVec3::NEG_Z]
            .into_iter()
            .map(|dir| View::perspective(eye, dir, pixels, tolerance))
            .collect()
    }

    fn looking(dir: DVec3, lens: Lens, pixels: usize, tolerance: f64) -> View {
        let dir = dir.normalize();
        let hint = if dir.y.abs() > 0.99 { DVec3::Z } else { DVec3::Y };
        let right = hint.cross(dir).normalize();
        let up = dir.cross(right);
        View {
            dir,
            right,
            up,
            lens,
            pixels,
            tolerance,
        }
    }

    /// Pixel coordinates (x, y) and depth (distance in front of the camera plane).
    pub fn project(&self, p: DVec3) -> DVec3 {
        let half = self.pixels as f64 / 2.0;
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let d = p - center;
                let scale = half / radius;
                DVec3::new(
                    (d.dot(self.right) + radius) * scale,
                    (d.dot(self.up) + radius) * scale,
                    radius - d.dot(self.dir),
                )
            }
            Lens::Perspective { eye } => {
                let d = p - eye;
                let z = -d.dot(self.dir);
                DVec3::new(
                    (d.dot(self.right) / z + 1.0) * half,
                    (d.dot(self.up) / z + 1.0) * half,
                    z,
                )
            }
        }
    }

    /// The point at pixel `index`'s centre and `depth`: [`View::project`] undone.
    pub fn unproject(&self, index: usize, depth: f64) -> DVec3 {
        let half = self.pixels as f64 / 2.0;
        let x = (index % self.pixels) as f64 + 0.5;
        let y = (index / self.pixels) as f64 + 0.5;
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let scale = radius / half;
                center
                    + self.right * (x * scale - radius)
                    + self.up * (y * scale - radius)
                    + self.dir * (radius - depth)
            }
            Lens::Perspective { eye } => {
                eye + (self.right * (x / half - 1.0) + self.up * (y / half - 1.0) - self.dir) * depth
            }
        }
    }

    /// For a GPU render of a perspective view: the matrix from points relative to `origin` to
    /// clip space, x and y as [`View::project`] has them before the divide, w the depth, and
    /// z = `near`, so that depth is near / w: reversed, with a float buffer's precision where it
    /// is needed, and compared with "greater". None for orthographic views.
    pub fn perspective_clip_matrix(&self, origin: DVec3, near: f64) -> Option<glam::DMat4> {
        let Lens::Perspective { eye } = self.lens else {
            return None;
        };
        let e = eye - origin;
        let row = |v: DVec3| glam::DVec4::new(v.x, v.y, v.z, -v.dot(e));
        let rows = [
            row(self.right),
            row(self.up),
            glam::DVec4::new(0.0, 0.0, 0.0, near),
            row(-self.dir),
        ];
        Some(glam::DMat4::from_cols_array_2d(&rows.map(|r| r.to_array())).transpose())
    }

    /// For the GPU rasterizer (shaders/raster.wgsl): three rows taking a point relative to
    /// `origin`, as (x, y, z, 1), to [`View::project`]'s pixel x, pixel y and depth. None for
    /// perspective views.
    pub fn ortho_rows(&self, origin: DVec3) -> Option<[[f64; 4]; 3]> {
        let [x, y, _, depth] = self.projection_rows(origin);
        matches!(self.lens, Lens::Orthographic { .. }).then_some([x, y, depth])
    }

    /// For the GPU (shaders/exposure.wgsl): four rows X, Y, W, Z taking a point relative to
    /// `origin`, as (x, y, z, 1), to [`View::project`]'s pixel (X / W, Y / W) and depth Z. W is 1
    /// for an orthographic view and the depth for a perspective one.
    pub fn projection_rows(&self, origin: DVec3) -> [[f64; 4]; 4] {
        let row = |axis: DVec3, scale: f64, constant: f64| {
            let v = axis * scale;
            [v.x, v.y, v.z, constant]
        };
        let half = self.pixels as f64 / 2.0;
        match self.lens {
            Lens::Orthographic { center, radius } => {
                let scale = half / radius;
                let offset = origin - center;
                [
                    row(self.right, scale, (offset.dot(self.right) + radius) * scale),
                    row(self.up, scale, (offset.dot(self.up) + radius) * scale),
                    [0.0, 0.0, 0.0, 1.0],
                    row(-self.dir, 1.0, radius - offset.dot(self.dir)),
                ]
            }
            Lens::Perspective { eye } => {
                let offset = origin - eye;
                let depth = row(-self.dir, 1.0, -offset.dot(self.dir));
                // Pixel x = (right · d / depth + 1) · half, so X = half · (right · d + depth).
                let numerator = |axis: DVec3| {
                    let r = row(axis, 1.0, offset.dot(axis));
                    [0, 1, 2, 3].map(|k| half * (r[k] + depth[k]))
                };
                [numerator(self.right), numerator(self.up), depth, depth]
            }
        }
    }

    /// Pixels per unit of length of an orthographic view; None for perspective views.
    pub fn ortho_scale(&self) -> Option<f64> {
        match self.lens {
            Lens::Orthographic { radius, .. } => Some(self.pixels as f64 / 2.0 / radius),
            Lens::Perspective { .. } => None,
        }
    }

    /// The depth tolerance of "nearer than" tests: 1e-4 of the framed diameter.
    pub fn depth_tolerance(&self) -> f64 {
        self.tolerance
    }
}

/// Calls `visit(pixel index, depth)` for every pixel centre the projected triangle covers.
/// Edges are inclusive, so triangles sharing an edge leave no crack.
pub fn rasterize(view: &View, tri: &[DVec3; 3], visit: impl FnMut(usize, f64)) {
    rasterize_with(view, tri, Coverage::Centres, visit);
}

/// Like [`rasterize`], but only pixels the triangle covers whole, each with the farthest depth
/// over the pixel: what an occluder certainly hides at this resolution.
pub fn rasterize_inner(view: &View, tri: &[DVec3; 3], visit: impl FnMut(usize, f64)) {
    rasterize_with(view, tri, Coverage::Whole, visit);
}

#[derive(Clone, Copy, PartialEq)]
enum Coverage {
    /// Pixels whose centre the triangle covers, at the centre's depth.
    Centres,
    /// Pixels wholly inside the triangle, at the farthest depth of their corners.
    Whole,
}

fn rasterize_with(view: &View, tri: &[DVec3; 3], coverage: Coverage, mut visit: impl FnMut(usize, f64)) {
    match view.lens {
        Lens::Orthographic { .. } => fill(view, tri.map(|v| view.project(v)), coverage, |d| d, &mut visit),
        Lens::Perspective { eye } => {
            // Clip to the near plane in front of the eye; 1/z is what varies linearly on screen.
            let near = view.tolerance;
            let z = tri.map(|v| -(v - eye).dot(view.dir));
            let mut poly: Vec<DVec3> = Vec::with_capacity(4);
            for k in 0..3 {
                let (a, b) = (k, (k + 1) % 3);
                if z[a] >= near {
                    poly.push(tri[a]);
                }
                if (z[a] >= near) != (z[b] >= near) {
                    let s = (near - z[a]) / (z[b] - z[a]);
                    poly.push(tri[a] + (tri[b] - tri[a]) * s);
                }
            }
            for k in 1..poly.len().saturating_sub(1) {
                let p = [poly[0], poly[k], poly[k + 1]].map(|v| {
                    let q = view.project(v);
                    DVec3::new(q.x, q.y, 1.0 / q.z)
                });
                fill(view, p, coverage, |w| 1.0 / w, &mut visit);
            }
        }
    }
}

/// Visits the pixels of the screen triangle `p` (x, y, a value that varies linearly on screen)
/// by `coverage`, with `depth` turning the interpolated value into a depth.
fn fill(
    view: &View,
    p: [DVec3; 3],
    coverage: Coverage,
    depth: impl Fn(f64) -> f64,
    visit: &mut impl FnMut(usize, f64),
) {
    let q = p.map(|v| v.truncate());
    let lo = q[0].min(q[1]).min(q[2]);
    let hi = q[0].max(q[1]).max(q[2]);
    let n = view.pixels as f64;
    // The pixels i whose sample points (the centre i + 0.5, or the whole [i, i + 1]) lie in
    // [lo, hi]. Most triangles of a detailed mesh cover none, so this comes first, without
    // rounding calls.
    let (inset, reach) = match coverage {
        Coverage::Centres => (0.5, 0.5),
        Coverage::Whole => (0.0, 1.0),
    };
    let pixels = |lo: f64, hi: f64| -> Option<(usize, usize)> {
        let (a, b) = ((lo - inset).max(0.0), (hi - reach).min(n - 1.0));
        // Also rejects NaN.
        if a.partial_cmp(&b).is_none_or(|o| o.is_gt()) {
            return None;
        }
        let first = a as usize + usize::from((a as usize as f64) < a);
        let last = b as usize;
        (first <= last).then_some((first, last))
    };
    let (Some((x0, x1)), Some((y0, y1))) = (pixels(lo.x, hi.x), pixels(lo.y, hi.y)) else {
        return;
    };
    let area = cross(q[1] - q[0], q[2] - q[0]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let weights = |c: DVec2| {
        [
            cross(q[2] - q[1], c - q[1]) / area,
            cross(q[0] - q[2], c - q[2]) / area,
            cross(q[1] - q[0], c - q[0]) / area,
        ]
    };
    let value = |w: [f64; 3]| w[0] * p[0].z + w[1] * p[1].z + w[2] * p[2].z;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (x_f, y_f) = (x as f64, y as f64);
            match coverage {
                Coverage::Centres => {
                    let w = weights(DVec2::new(x_f + 0.5, y_f + 0.5));
                    if w.iter().all(|&v| v >= 0.0) {
                        visit(y * view.pixels + x, depth(value(w)));
                    }
                }
                Coverage::Whole => {
                    let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                        .map(|(dx, dy)| weights(DVec2::new(x_f + dx, y_f + dy)));
                    if corners.iter().flatten().all(|&v| v >= 0.0) {
                        let farthest = corners
                            .iter()
                            .map(|&w| depth(value(w)))
                            .fold(f64::NEG_INFINITY, f64::max);
                        visit(y * view.pixels + x, farthest);
                    }
                }
            }
        }
    }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Calls `visit(pixel index, depth)` for every pixel centre each triangle of `mesh` covers.
/// Orthographic views project each vertex once.
pub fn rasterize_mesh(view: &View, mesh: &Mesh, mut visit: impl FnMut(usize, f64)) {
    match view.lens {
        Lens::Orthographic { .. } => {
            let projected: Vec<DVec3> = mesh.positions.iter().map(|p| view.project(p.as_dvec3())).collect();
            for t in &mesh.triangles {
                fill(
                    view,
                    t.map(|i| projected[i as usize]),
                    Coverage::Centres,
                    |d| d,
                    &mut visit,
                );
            }
        }
        Lens::Perspective { .. } => {
            for tri in mesh.triangles_f64() {
                rasterize(view, &tri, &mut visit);
            }
        }
    }
}

/// The nearest depth per pixel, `f32::INFINITY` where nothing is drawn.
pub fn depth_image(view: &View, mesh: &Mesh) -> Vec<f32> {
    let mut depth = vec![f32::INFINITY; view.pixels * view.pixels];
    rasterize_mesh(view, mesh, |i, d| depth[i] = depth[i].min(d as f32));
    depth
}

/// Depth images of `mesh` in `views`: on `gpu` where one is given and can draw them
/// (orthographic views, a mesh within one storage binding), else on the CPU.
pub fn depth_images(views: &[View], mesh: &Mesh, gpu: Option<&Gpu>) -> Result<Vec<Vec<f32>>, GpuError> {
    if let Some(gpu) = gpu {
        match crate::gpu::raster::depth_images(gpu, mesh, views) {
            Err(GpuError::Unsupported(why)) => tracing::debug!("depth images on the CPU: {why}"),
            drawn => return drawn,
        }
    }
    Ok(views.par_iter().map(|view| depth_image(view, mesh)).collect())
}

/// A coverage bitmask, one bit per pixel.
pub fn coverage_mask(view: &View, mesh: &Mesh) -> Vec<u64> {
    let mut mask = vec![0u64; (view.pixels * view.pixels).div_ceil(64)];
    rasterize_mesh(view, mesh, |i, _| mask[i / 64] |= 1 << (i % 64));
    mask
}

#[cfg(test)]
mod tests {
    use super::View;
    use glam::DVec3;

    #[test]
    fn projection_rows_project_as_the_view_does() {
        let origin = DVec3::new(0.5, 0.25, -1.0);
        let views = [
            View::new(DVec3::new(0.2, 0.9, -0.4), DVec3::new(1.0, 2.0, 3.0), 5.0, 64),
            View::perspective(DVec3::new(0.3, -1.0, 2.0), DVec3::new(-0.5, 0.1, 0.8), 64, 1e-3),
        ];
        for view in views {
            let rows = view.projection_rows(origin);
            for p in [DVec3::new(1.0, 2.0, 3.0), DVec3::new(-0.7, -2.0, 0.4)] {
                let h = (p - origin).extend(1.0);
                let [x, y, w, z] = rows.map(|r| glam::DVec4::from_array(r).dot(h));
                let q = view.project(p);
                assert!(DVec3::new(x / w, y / w, z).distance(q) < 1e-9, "{q}");
            }
        }
    }

    #[test]
    fn unproject_undoes_project_at_pixel_centres() {
        let eye = DVec3::new(0.3, -1.0, 2.0);
        let views = [
            View::new(DVec3::new(0.2, 0.9, -0.4), DVec3::new(1.0, 2.0, 3.0), 5.0, 64),
            View::perspective(eye, DVec3::new(-0.5, 0.1, 0.8), 64, 1e-3),
        ];
        for view in views {
            for (index, depth) in [(0, 0.5), (64 * 31 + 17, 2.0), (64 * 64 - 1, 7.5)] {
                let q = view.project(view.unproject(index, depth));
                let centre = DVec3::new((index % 64) as f64 + 0.5, (index / 64) as f64 + 0.5, depth);
                assert!(q.distance(centre) < 1e-9, "{q} against {centre}");
            }
        }
    }
}
