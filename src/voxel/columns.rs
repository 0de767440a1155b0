//! Where vertical rays (+z) through points cross the surface, and in which direction.
//!
//! The point-in-triangle test uses exact tie-breaking (simulation of simplicity: the point is
//! moved by (ε, ε²)), and every edge is evaluated in one canonical direction, so the triangles
//! that share an edge always agree: a ray through an edge or a vertex of a closed surface is
//! counted exactly once.

use super::Grid;
use crate::mesh::Mesh;
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
    let q = tri.map(|v| [v[0], v[1]]);
    let w0 = edge_side(q[1], q[2], p);
    let w1 = edge_side(q[2], q[0], p);
    let w2 = edge_side(q[0], q[1], p);
    let s = w0.1;
    if s == 0 || w1.1 != s || w2.1 != s {
        return None;
    }
    let total = w0.0 + w1.0 + w2.0;
    let z = if total != F::zero() {
        (w0.0 * tri[0][2] + w1.0 * tri[1][2] + w2.0 * tri[2][2]) / total
    } else {
        // The point sits on a vertex up to rounding; any corner height is right.
        tri[0][2]
    };
    Some(Crossing { z, sign: s })
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
