//! Orthographic software rasterization at pixel centres: depth images of meshes and coverage
//! masks of boxes.

use glam::{DVec2, DVec3};

/// An orthographic camera framing a bounding sphere into `pixels` × `pixels`.
#[derive(Clone, Debug)]
pub struct View {
    /// Unit vector from the sphere's centre towards the camera.
    pub dir: DVec3,
    right: DVec3,
    up: DVec3,
    center: DVec3,
    radius: f64,
    pub pixels: usize,
}

impl View {
    pub fn new(dir: DVec3, center: DVec3, radius: f64, pixels: usize) -> View {
        let dir = dir.normalize();
        let hint = if dir.y.abs() > 0.99 { DVec3::Z } else { DVec3::Y };
        let right = hint.cross(dir).normalize();
        let up = dir.cross(right);
        View {
            dir,
            right,
            up,
            center,
            radius: radius.max(1e-12),
            pixels,
        }
    }

    /// Pixel coordinates (x, y) and depth (distance in front of the camera plane).
    pub fn project(&self, p: DVec3) -> DVec3 {
        let d = p - self.center;
        let scale = self.pixels as f64 / (2.0 * self.radius);
        DVec3::new(
            (d.dot(self.right) + self.radius) * scale,
            (d.dot(self.up) + self.radius) * scale,
            self.radius - d.dot(self.dir),
        )
    }

    /// The depth tolerance of "nearer than" tests: 1e-4 of the sphere's diameter.
    pub fn depth_tolerance(&self) -> f64 {
        2e-4 * self.radius
    }
}

/// Calls `visit(pixel index, depth)` for every pixel centre the projected triangle covers.
/// Edges are inclusive, so triangles sharing an edge leave no crack.
pub fn rasterize(view: &View, tri: &[DVec3; 3], mut visit: impl FnMut(usize, f64)) {
    let p = tri.map(|v| view.project(v));
    let q = p.map(|v| v.truncate());
    let area = cross(q[1] - q[0], q[2] - q[0]);
    if area == 0.0 {
        return;
    }
    let n = view.pixels as f64;
    let lo = q[0].min(q[1]).min(q[2]);
    let hi = q[0].max(q[1]).max(q[2]);
    let x0 = (lo.x - 0.5).ceil().max(0.0) as usize;
    let y0 = (lo.y - 0.5).ceil().max(0.0) as usize;
    let x1 = (hi.x - 0.5).floor().min(n - 1.0);
    let y1 = (hi.y - 0.5).floor().min(n - 1.0);
    if x1 < 0.0 || y1 < 0.0 {
        return;
    }
    for y in y0..=y1 as usize {
        for x in x0..=x1 as usize {
            let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            let w0 = cross(q[2] - q[1], c - q[1]) / area;
            let w1 = cross(q[0] - q[2], c - q[2]) / area;
            let w2 = cross(q[1] - q[0], c - q[0]) / area;
            if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                visit(y * view.pixels + x, w0 * p[0].z + w1 * p[1].z + w2 * p[2].z);
            }
        }
    }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// The nearest depth per pixel, `f32::INFINITY` where nothing is drawn.
pub fn depth_image(view: &View, triangles: impl Iterator<Item = [DVec3; 3]>) -> Vec<f32> {
    let mut depth = vec![f32::INFINITY; view.pixels * view.pixels];
    for tri in triangles {
        rasterize(view, &tri, |i, d| depth[i] = depth[i].min(d as f32));
    }
    depth
}

/// A coverage bitmask, one bit per pixel.
pub fn coverage_mask(view: &View, triangles: impl Iterator<Item = [DVec3; 3]>) -> Vec<u64> {
    let mut mask = vec![0u64; (view.pixels * view.pixels).div_ceil(64)];
    for tri in triangles {
        rasterize(view, &tri, |i, _| mask[i / 64] |= 1 << (i % 64));
    }
    mask
}
