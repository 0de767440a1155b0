//! Where vertical rays (+z) through points cross the surface, and in which direction.
//!
//! The point-in-triangle test uses exact tie-breaking (simulation of simplicity: the point is
//! moved by (ε, ε²)), and every edge is evaluated in one canonical direction, so the triangles
//! that share an edge always agree: a ray through an edge or a vertex of a closed surface is
//! counted exactly once.

use super::Grid;
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;

/// One crossing of a vertical ray with a triangle: its height, and +1 where the triangle faces
/// up (the ray leaves the solid there), -1 where it faces down.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    pub z: f64,
    pub sign: i8,
}

/// Where the vertical line through `p` meets triangle `tri`, if it does.
pub fn column_hit(tri: &[DVec3; 3], p: DVec2) -> Option<Crossing> {
    let q = tri.map(|v| v.truncate());
    let w0 = edge_side(q[1], q[2], p);
    let w1 = edge_side(q[2], q[0], p);
    let w2 = edge_side(q[0], q[1], p);
    let s = w0.1;
    if s == 0 || w1.1 != s || w2.1 != s {
        return None;
    }
    let total = w0.0 + w1.0 + w2.0;
    let z = if total != 0.0 {
        (w0.0 * tri[0].z + w1.0 * tri[1].z + w2.0 * tri[2].z) / total
    } else {
        // The point sits on a vertex up to rounding; any corner height is right.
        tri[0].z
    };
    Some(Crossing { z, sign: s })
}

/// The side of the directed edge a→b on which `p` lies: (the signed area, its sign with ties
/// broken by perturbing `p`). Computed for the lexicographically ordered edge so that the two
/// triangles sharing an edge see exactly opposite values.
fn edge_side(a: DVec2, b: DVec2, p: DVec2) -> (f64, i8) {
    let (a, b, flip) = if (a.x, a.y) < (b.x, b.y) {
        (a, b, 1.0)
    } else {
        (b, a, -1.0)
    };
    let area = (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
    let tie = if area != 0.0 {
        area
    } else if b.y != a.y {
        -(b.y - a.y)
    } else {
        b.x - a.x
    };
    let sign = if tie > 0.0 {
        1
    } else if tie < 0.0 {
        -1
    } else {
        0
    };
    (flip * area, (flip as i8) * sign)
}

/// The crossings of every voxel column of a grid, sorted by height within each column.
pub struct ColumnCrossings {
    /// Column `c` (= x * ny + y) owns `crossings[offsets[c]..offsets[c + 1]]`.
    pub offsets: Vec<usize>,
    pub crossings: Vec<Crossing>,
}

impl ColumnCrossings {
    pub fn build(mesh: &Mesh, grid: &Grid) -> ColumnCrossings {
        let [nx, ny, _] = grid.dims;
        let mut hits: Vec<(u32, Crossing)> = (0..mesh.triangles.len())
            .into_par_iter()
            .flat_map_iter(|t| {
                let tri = mesh.corners(t).map(|p| p.as_dvec3());
                let lo = tri[0].min(tri[1]).min(tri[2]);
                let hi = tri[0].max(tri[1]).max(tri[2]);
                let [rx, ry, _] = grid.voxel_range(lo, hi);
                let mut out = Vec::new();
                for x in rx {
                    for y in ry.clone() {
                        let p = grid.center(x, y, 0).truncate();
                        if let Some(c) = column_hit(&tri, p) {
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

    pub fn column(&self, c: usize) -> &[Crossing] {
        &self.crossings[self.offsets[c]..self.offsets[c + 1]]
    }

    /// For each voxel of column `c`, from z = 0 upwards, the crossings above its centre:
    /// `(signed sum, count)`.
    pub fn above(&self, grid: &Grid, c: usize) -> impl Iterator<Item = (i32, u32)> + '_ {
        let column = self.column(c);
        let total: i32 = column.iter().map(|h| i32::from(h.sign)).sum();
        let (x, y) = (c / grid.dims[1], c % grid.dims[1]);
        let mut below = 0usize;
        let mut below_sum = 0i32;
        let grid = grid.clone();
        (0..grid.dims[2]).map(move |z| {
            let zc = grid.center(x, y, z).z;
            while below < column.len() && column[below].z <= zc {
                below_sum += i32::from(column[below].sign);
                below += 1;
            }
            (total - below_sum, (column.len() - below) as u32)
        })
    }
}
