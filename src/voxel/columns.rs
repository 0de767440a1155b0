//! Where vertical rays (+z) through points cross the surface, and in which direction.
//!
//! The point-in-triangle test uses exact tie-breaking (simulation of simplicity: the point is
//! moved by (ε, ε²)), and every edge is evaluated in one canonical direction, so the triangles
//! that share an edge always agree: a ray through an edge or a vertex of a closed surface is
//! counted exactly once.

use super::Grid;
use crate::geom::clamped_index;
use crate::mesh::Mesh;
use crate::mesh::buckets::Buckets;
use glam::{DVec2, DVec3};
use num_traits::Float;
use rayon::prelude::*;

/// One crossing of a vertical ray with a triangle: its height, and +1 where the triangle faces
/// up (the ray leaves the solid there), -1 where it faces down.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing<F> {
    pub z: F,
    pub sign: i8,
}

/// Where the vertical line through `p` meets triangle `tri`, if it does, at any float
/// precision; the order of operations matches `column_hit` in shaders/common.wgsl.
pub fn column_hit<F: Float>(tri: &[[F; 3]; 3], p: [F; 2]) -> Option<Crossing<F>> {
    let ([w0, w1, w2], sign) = column_weights(tri, p)?;
    let total = w0 + w1 + w2;
    let z = if total != F::zero() {
        (w0 * tri[0][2] + w1 * tri[1][2] + w2 * tri[2][2]) / total
    } else {
        // The point sits on a vertex up to rounding; any corner height is right.
        tri[0][2]
    };
    Some(Crossing { z, sign })
}

/// The sign of [`column_hit`]'s crossing, if the line meets the triangle, without its height:
/// for counts of crossings.
pub fn column_sign<F: Float>(tri: &[[F; 3]; 3], p: [F; 2]) -> Option<i8> {
    column_weights(tri, p).map(|(_, sign)| sign)
}

/// The signed areas `p` makes with each edge, opposite each corner, and the side it lies on,
/// where the line through `p` meets the triangle.
fn column_weights<F: Float>(tri: &[[F; 3]; 3], p: [F; 2]) -> Option<([F; 3], i8)> {
    let q = tri.map(|v| [v[0], v[1]]);
    let w0 = edge_side(q[1], q[2], p);
    let w1 = edge_side(q[2], q[0], p);
    let w2 = edge_side(q[0], q[1], p);
    let s = w0.1;
    (s != 0 && w1.1 == s && w2.1 == s).then_some(([w0.0, w1.0, w2.0], s))
}

/// The side of the directed edge a→b on which `p` lies: (the signed area, its sign with ties
/// broken by perturbing `p`). Computed for the lexicographically ordered edge so that the two
/// triangles sharing an edge see exactly opposite values.
fn edge_side<F: Float>(a: [F; 2], b: [F; 2], p: [F; 2]) -> (F, i8) {
    let (a, b, flip) = if (a[0], a[1]) < (b[0], b[1]) {
        (a, b, 1)
    } else {
        (b, a, -1)
    };
    let area = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let tie = if area != F::zero() {
        area
    } else if b[1] != a[1] {
        -(b[1] - a[1])
    } else {
        b[0] - a[0]
    };
    let sign = if tie > F::zero() {
        1
    } else if tie < F::zero() {
        -1
    } else {
        0
    };
    let signed = if flip > 0 { area } else { -area };
    (signed, flip * sign)
}

/// How many voxel centres of a column of `n` lie below height `z` (k + 0.5 < z), in voxel
/// units: `voxels_below` in shaders/common.wgsl.
pub fn voxels_below(z: f32, n: usize) -> usize {
    ((z - 0.5).ceil() as i32).clamp(0, n as i32) as usize
}

/// The crossings of every voxel column of a grid, sorted by height within each column.
pub struct ColumnCrossings {
    /// Column `c` (= x * ny + y) owns `crossings[offsets[c]..offsets[c + 1]]`.
    pub offsets: Vec<usize>,
    pub crossings: Vec<Crossing<f32>>,
}

impl ColumnCrossings {
    pub fn build(mesh: &Mesh, grid: &Grid) -> ColumnCrossings {
        let [nx, ny, _] = grid.dims;
        let mut hits: Vec<(u32, Crossing<f32>)> = grid
            .local_triangles(mesh)
            .par_iter()
            .flat_map_iter(|tri| {
                let [rx, ry, _] = Grid::local_spans(tri, grid.dims);
                let mut out = Vec::new();
                for x in rx {
                    for y in ry.clone() {
                        let p = [x as f32 + 0.5, y as f32 + 0.5];
                        if let Some(c) = column_hit(tri, p) {
                            out.push(((x * ny + y) as u32, c));
                        }
                    }
                }
                out
            })
            .collect();
        hits.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.z.total_cmp(&b.1.z)));
        let mut offsets = vec![0usize; nx * ny + 1];
        for &(c, _) in &hits {
            offsets[c as usize + 1] += 1;
        }
        for c in 0..nx * ny {
            offsets[c + 1] += offsets[c];
        }
        ColumnCrossings {
            offsets,
            crossings: hits.into_iter().map(|(_, c)| c).collect(),
        }
    }

    pub fn column(&self, c: usize) -> &[Crossing<f32>] {
        &self.crossings[self.offsets[c]..self.offsets[c + 1]]
    }

    /// For each voxel of column `c`, from z = 0 upwards, the crossings above its centre:
    /// `(signed sum, count)`.
    pub fn above(&self, grid: &Grid, c: usize) -> impl Iterator<Item = (i32, u32)> + '_ {
        let column = self.column(c);
        let total: i32 = column.iter().map(|h| i32::from(h.sign)).sum();
        let nz = grid.dims[2];
        let mut below = 0usize;
        let mut below_sum = 0i32;
        (0..nz).map(move |z| {
            while below < column.len() && voxels_below(column[below].z, nz) <= z {
                below_sum += i32::from(column[below].sign);
                below += 1;
            }
            (total - below_sum, (column.len() - below) as u32)
        })
    }
}

/// A mesh's triangles bucketed by their xy footprint, so that a vertical line meets only the
/// triangles of its bucket.
pub struct ColumnIndex {
    /// The footprint's least corner, the buckets' side and their count along x and y.
    lo: DVec2,
    cell: f64,
    dims: [usize; 2],
    /// Bucket x·dims[1] + y's triangles.
    buckets: Buckets<u32>,
}

impl ColumnIndex {
    pub fn new(mesh: &Mesh) -> ColumnIndex {
        let (lo, hi) = mesh.bounds();
        let (lo, hi) = (lo.as_dvec3().truncate(), hi.as_dvec3().truncate());
        let extent = (hi - lo).max(DVec2::splat(1e-9));
        // About four triangles per bucket on a surface spread over the footprint.
        let cells = ((mesh.triangles.len() as f64 / 4.0).sqrt().ceil() as usize).clamp(1, 1024);
        let cell = extent.max_element() / cells as f64;
        let dims = [
            (extent.x / cell).ceil() as usize + 1,
            (extent.y / cell).ceil() as usize + 1,
        ];
        // Each triangle's buckets, first and past the last along x and y, found in parallel.
        let spans: Vec<[u32; 4]> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|t| {
                let tri = mesh.corners(t).map(|v| v.as_dvec3().truncate());
                let (a, b) = (tri[0].min(tri[1]).min(tri[2]), tri[0].max(tri[1]).max(tri[2]));
                let along = |p: DVec2, k: usize| clamped_index((p[k] - lo[k]) / cell, dims[k]) as u32;
                [along(a, 0), along(a, 1), along(b, 0) + 1, along(b, 1) + 1]
            })
            .collect();
        let pairs = spans.iter().zip(0u32..).flat_map(|(&[x0, y0, x1, y1], t)| {
            (x0..x1).flat_map(move |x| (y0..y1).map(move |y| (x as usize * dims[1] + y as usize, t)))
        });
        ColumnIndex {
            lo,
            cell,
            dims,
            buckets: Buckets::new(dims[0] * dims[1], pairs),
        }
    }

    /// The triangles of the bucket that holds `p`'s footprint: every one the vertical line
    /// through `p` may meet. None outside the mesh's footprint.
    pub fn triangles_at(&self, p: DVec3) -> &[u32] {
        let q = (p.truncate() - self.lo) / self.cell;
        if q.x >= 0.0 && q.y >= 0.0 && (q.x as usize) < self.dims[0] && (q.y as usize) < self.dims[1] {
            self.buckets.get(q.x as usize * self.dims[1] + q.y as usize)
        } else {
            &[]
        }
    }

    /// The triangles whose footprint buckets meet the xy box [lo, hi]: a superset of those
    /// that reach into it, sorted.
    pub fn triangles_over(&self, lo: DVec2, hi: DVec2) -> Vec<u32> {
        let bucket = |p: DVec2, k: usize| clamped_index((p[k] - self.lo[k]) / self.cell, self.dims[k]);
        let mut out = Vec::new();
        for x in bucket(lo, 0)..=bucket(hi, 0) {
            for y in bucket(lo, 1)..=bucket(hi, 1) {
                out.extend_from_slice(self.buckets.get(x * self.dims[1] + y));
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }
}
