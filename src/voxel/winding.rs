//! The generalized winding number (Jacobson et al. 2013), w(p) = Σ solid angle / 4π, and the
//! inside test w ≥ 0.5.
//!
//! Summing every triangle's solid angle at every voxel costs voxels × triangles. Instead, close
//! the surface with a curtain swept from its open boundary straight down to infinity. The upward
//! ray from p never meets that curtain, so for the closed surface w is the signed count of
//! crossings above p, and the open surface's w is that count plus the curtain's solid angle,
//! which needs only the boundary edges:
//!
//! w(p) = Σ_{crossings above p} sign + 1/4π Σ_{boundary edges a→b} Ω(a − p, b − p, −z)
//!
//! Closed meshes have no boundary edges and cost one column pass.

pub mod gpu;

use super::{Grid, columns::ColumnCrossings, columns::column_hit};
use crate::mesh::{BoundaryEdge, Mesh};
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Voxels between exact evaluations of the curtain term along a column.
const STRIDE: usize = 8;
/// Interpolation is trusted where the term changes less than this between samples and the
/// interpolated w is farther than `MARGIN` from the threshold.
const MAX_STEP: f64 = 0.05;
const MARGIN: f64 = 0.15;

/// Which voxel centres have w ≥ 0.5.
///
/// The curtain hangs straight down and a column runs straight up, so along a column the curtain
/// term is continuous, and smooth away from the boundary edges. It is computed exactly every
/// `STRIDE` voxels and interpolated between, except where it changes fast (near an edge) or the
/// result is close to the threshold: there every voxel is computed exactly.
pub fn classify(crossings: &ColumnCrossings, mesh: &Mesh, boundary: &[BoundaryEdge], grid: &Grid) -> Vec<bool> {
    let mut inside = vec![false; grid.len()];
    let (ny, nz) = (grid.dims[1], grid.dims[2]);
    inside.par_chunks_mut(nz).enumerate().for_each(|(c, column)| {
        let counts: Vec<f64> = crossings.above(grid, c).map(|(sum, _)| f64::from(sum)).collect();
        if boundary.is_empty() {
            for (voxel, count) in column.iter_mut().zip(&counts) {
                *voxel = *count >= 0.5;
            }
            return;
        }
        let term = |z: usize| boundary_term(mesh, boundary, grid.center(c / ny, c % ny, z));
        let mut samples: Vec<usize> = (0..nz).step_by(STRIDE).collect();
        if samples.last() != Some(&(nz - 1)) {
            samples.push(nz - 1);
        }
        let terms: Vec<f64> = samples.iter().map(|&z| term(z)).collect();
        for (&z, &b) in samples.iter().zip(&terms) {
            column[z] = counts[z] + b >= 0.5;
        }
        for k in 1..samples.len() {
            let (z0, z1, b0, b1) = (samples[k - 1], samples[k], terms[k - 1], terms[k]);
            let smooth = (b1 - b0).abs() < MAX_STEP;
            for z in z0 + 1..z1 {
                let estimate = counts[z] + b0 + (b1 - b0) * (z - z0) as f64 / (z1 - z0) as f64;
                column[z] = if smooth && (estimate - 0.5).abs() > MARGIN {
                    estimate >= 0.5
                } else {
                    counts[z] + term(z) >= 0.5
                };
            }
        }
    });
    inside
}

/// The solid angle of the triangle (a, b, c) seen from the origin (Van Oosterom & Strackee),
/// positive when the triangle winds counter-clockwise as seen from the origin's far side.
pub fn solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let numerator = a.dot(b.cross(c));
    let denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * numerator.atan2(denominator)
}

/// The curtain's share of w(p), from the open boundary alone.
pub fn boundary_term(mesh: &Mesh, boundary: &[BoundaryEdge], p: DVec3) -> f64 {
    let sum: f64 = boundary
        .iter()
        .map(|e| {
            let a = mesh.positions[e.a as usize].as_dvec3() - p;
            let b = mesh.positions[e.b as usize].as_dvec3() - p;
            f64::from(e.weight) * solid_angle(a, b, DVec3::NEG_Z)
        })
        .sum();
    sum / (4.0 * PI)
}

/// w(p) by its definition, summing every triangle: the reference the fast forms are tested on.
pub fn direct(mesh: &Mesh, p: DVec3) -> f64 {
    let sum: f64 = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.corners(t).map(|v| v.as_dvec3() - p);
            solid_angle(a, b, c)
        })
        .sum();
    sum / (4.0 * PI)
}

/// w at arbitrary points: triangles bucketed by their xy footprint, so that a query tests only
/// the triangles above and below it.
pub struct WindingField<'a> {
    mesh: &'a Mesh,
    boundary: &'a [BoundaryEdge],
    lo: DVec2,
    cell: f64,
    dims: [usize; 2],
    offsets: Vec<usize>,
    triangles: Vec<u32>,
}

impl<'a> WindingField<'a> {
    pub fn new(mesh: &'a Mesh, boundary: &'a [BoundaryEdge]) -> WindingField<'a> {
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
        let range = |t: usize| {
            let tri = mesh.corners(t).map(|v| v.as_dvec3().truncate());
            let a = ((tri[0].min(tri[1]).min(tri[2]) - lo) / cell).floor();
            let b = ((tri[0].max(tri[1]).max(tri[2]) - lo) / cell).floor();
            let clamp = |v: f64, k: usize| (v.max(0.0) as usize).min(dims[k] - 1);
            (clamp(a.x, 0)..=clamp(b.x, 0), clamp(a.y, 1)..=clamp(b.y, 1))
        };
        let mut offsets = vec![0usize; dims[0] * dims[1] + 1];
        for t in 0..mesh.triangles.len() {
            let (rx, ry) = range(t);
            for x in rx {
                for y in ry.clone() {
                    offsets[x * dims[1] + y + 1] += 1;
                }
            }
        }
        for i in 0..dims[0] * dims[1] {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut triangles = vec![0u32; offsets[dims[0] * dims[1]]];
        for t in 0..mesh.triangles.len() {
            let (rx, ry) = range(t);
            for x in rx {
                for y in ry.clone() {
                    let slot = &mut fill[x * dims[1] + y];
                    triangles[*slot] = t as u32;
                    *slot += 1;
                }
            }
        }
        WindingField {
            mesh,
            boundary,
            lo,
            cell,
            dims,
            offsets,
            triangles,
        }
    }

    /// The triangles whose footprint buckets meet the xy box [lo, hi]: a superset of those
    /// that reach into it, sorted.
    pub fn triangles_over(&self, lo: DVec2, hi: DVec2) -> Vec<u32> {
        let bucket =
            |p: DVec2, k: usize| (((p[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1);
        let mut out = Vec::new();
        for x in bucket(lo, 0)..=bucket(hi, 0) {
            for y in bucket(lo, 1)..=bucket(hi, 1) {
                let b = x * self.dims[1] + y;
                out.extend_from_slice(&self.triangles[self.offsets[b]..self.offsets[b + 1]]);
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    pub fn winding(&self, p: DVec3) -> f64 {
        f64::from(self.crossings_above(p).0) + boundary_term(self.mesh, self.boundary, p)
    }

    /// The crossings of the upward ray from `p`: (signed sum, count). On a closed surface the
    /// sum is w(p) and the count's parity is the parity test.
    pub fn crossings_above(&self, p: DVec3) -> (i32, u32) {
        let q = (p.truncate() - self.lo) / self.cell;
        let (mut sum, mut count) = (0i32, 0u32);
        if q.x >= 0.0 && q.y >= 0.0 && (q.x as usize) < self.dims[0] && (q.y as usize) < self.dims[1] {
            let b = q.x as usize * self.dims[1] + q.y as usize;
            for &t in &self.triangles[self.offsets[b]..self.offsets[b + 1]] {
                let tri = self.mesh.corners(t as usize).map(|v| v.as_dvec3().to_array());
                if let Some(hit) = column_hit(&tri, [p.x, p.y])
                    && hit.z > p.z
                {
                    sum += i32::from(hit.sign);
                    count += 1;
                }
            }
        }
        (sum, count)
    }
}
