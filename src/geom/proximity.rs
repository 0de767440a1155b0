//! Whether a point lies on a mesh's surface, or near a part of it that it does not touch, within
//! a tolerance: triangles bucketed in a uniform grid, exact point–triangle distances in the
//! buckets.

use crate::mesh::Mesh;
use crate::mesh::buckets::Buckets;
use glam::DVec3;
use rayon::prelude::*;
use std::ops::Range;

pub struct SurfaceIndex<'a> {
    mesh: &'a Mesh,
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
    tolerance: f64,
    /// Bucket `b` holds `triangles[offsets[b]..offsets[b + 1]]`.
    offsets: Vec<usize>,
    triangles: Vec<u32>,
}

impl<'a> SurfaceIndex<'a> {
    pub fn new(mesh: &'a Mesh, tolerance: f64) -> SurfaceIndex<'a> {
        let (lo, hi) = mesh.bounds();
        let (lo, hi) = (lo.as_dvec3() - tolerance, hi.as_dvec3() + tolerance);
        let per_axis = ((mesh.triangles.len() as f64).cbrt() * 2.0).clamp(1.0, 64.0);
        let cell = ((hi - lo).max_element() / per_axis).max(1e-12);
        let dims = ((hi - lo) / cell).to_array().map(|e| (e.ceil() as usize).max(1));
        let mut index = SurfaceIndex {
            mesh,
            lo,
            cell,
            dims,
            tolerance,
            offsets: Vec::new(),
            triangles: Vec::new(),
        };
        // Each triangle's buckets found in parallel; grouped in the triangles' order.
        let reached: Vec<[Range<usize>; 3]> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|t| {
                let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
                index.bucket_range(a.min(b).min(c) - tolerance, a.max(b).max(c) + tolerance)
            })
            .collect();
        let each = reached.iter().zip(0u32..).flat_map(|([rx, ry, rz], t)| {
            let index = &index;
            rx.clone().flat_map(move |x| {
                ry.clone()
                    .flat_map(move |y| rz.clone().map(move |z| (index.bucket(x, y, z), t)))
            })
        });
        let Buckets { starts, items } = Buckets::new(dims.iter().product(), each);
        (index.offsets, index.triangles) = (starts, items);
        index
    }

    fn bucket_range(&self, lo: DVec3, hi: DVec3) -> [Range<usize>; 3] {
        std::array::from_fn(|k| {
            let a = ((lo[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize;
            let b = ((hi[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize;
            a.min(self.dims[k] - 1)..b.min(self.dims[k] - 1) + 1
        })
    }

    fn bucket(&self, x: usize, y: usize, z: usize) -> usize {
        (x * self.dims[1] + y) * self.dims[2] + z
    }

    /// Whether `p` is within the tolerance of some triangle.
    pub fn on_surface(&self, p: DVec3) -> bool {
        self.any_near(p, |_, distance| distance <= self.tolerance)
    }

    /// Whether a triangle with neither of `corners` as a corner lies within the tolerance of
    /// `p`, but farther than `touching`: a part of the surface near `p` that does not touch it.
    pub fn near_apart(&self, p: DVec3, touching: f64, corners: [u32; 2]) -> bool {
        self.any_near(p, |t, distance| {
            distance <= self.tolerance
                && distance > touching
                && !self.mesh.triangles[t].iter().any(|v| corners.contains(v))
        })
    }

    /// The distance from `p` to the nearest triangle within the tolerance for which
    /// `wanted(triangle)` holds, if there is one.
    pub fn nearest_where(&self, p: DVec3, wanted: impl Fn(usize) -> bool) -> Option<f64> {
        self.bucket_at(p)
            .iter()
            .filter(|&&t| wanted(t as usize))
            .map(|&t| self.distance(t as usize, p))
            .filter(|&d| d <= self.tolerance)
            .min_by(f64::total_cmp)
    }

    /// Whether `accept(triangle, its distance from p)` holds for a triangle in `p`'s bucket.
    fn any_near(&self, p: DVec3, accept: impl Fn(usize, f64) -> bool) -> bool {
        self.bucket_at(p)
            .iter()
            .any(|&t| accept(t as usize, self.distance(t as usize, p)))
    }

    /// The triangles of `p`'s bucket: every one within the tolerance of `p`, and some farther.
    fn bucket_at(&self, p: DVec3) -> &[u32] {
        let [rx, ry, rz] = self.bucket_range(p, p);
        let b = self.bucket(rx.start, ry.start, rz.start);
        &self.triangles[self.offsets[b]..self.offsets[b + 1]]
    }

    fn distance(&self, t: usize, p: DVec3) -> f64 {
        let [a, b, c] = self.mesh.corners(t).map(|v| v.as_dvec3());
        closest_on_triangle(p, a, b, c).distance(p)
    }
}

/// The point of triangle (a, b, c) closest to `p` (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denominator = va + vb + vc;
    if denominator == 0.0 {
        // Degenerate: the nearest corner will do.
        return [a, b, c]
            .into_iter()
            .min_by(|x, y| x.distance_squared(p).total_cmp(&y.distance_squared(p)))
            .expect("three corners");
    }
    a + ab * (vb / denominator) + ac * (vc / denominator)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn points_on_and_off_a_triangle() {
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        let index = SurfaceIndex::new(&mesh, 1e-4);
        assert!(index.on_surface(DVec3::new(0.25, 0.25, 0.0)));
        assert!(index.on_surface(DVec3::new(0.25, 0.25, 5e-5)));
        assert!(!index.on_surface(DVec3::new(0.25, 0.25, 1e-3)));
        assert!(!index.on_surface(DVec3::new(0.75, 0.75, 0.0)));
        assert!(index.on_surface(DVec3::new(1.00005, 0.0, 0.0)));
    }
}
