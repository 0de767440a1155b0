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
use std::collections::HashMap;
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
    // Per voxel of column c, the signed count of the surface's crossings above it.
    let counts_above = |c: usize| -> Vec<f64> { crossings.above(grid, c).map(|(sum, _)| f64::from(sum)).collect() };
    if boundary.is_empty() {
        inside.par_chunks_mut(nz).enumerate().for_each(|(c, column)| {
            for (voxel, count) in column.iter_mut().zip(counts_above(c)) {
                *voxel = count >= 0.5;
            }
        });
        return inside;
    }
    let curtain = Curtain::new(mesh, boundary);
    let mut samples: Vec<usize> = (0..nz).step_by(STRIDE).collect();
    if samples.last() != Some(&(nz - 1)) {
        samples.push(nz - 1);
    }
    inside
        .par_chunks_mut(nz * COLUMNS_TOGETHER)
        .enumerate()
        .for_each(|(batch, columns)| {
            let first = batch * COLUMNS_TOGETHER;
            let centre = |(k, z): (usize, usize)| grid.center((first + k) / ny, (first + k) % ny, z);
            let counts: Vec<Vec<f64>> = (first..first + columns.len() / nz).map(counts_above).collect();
            let sampled: Vec<DVec3> = (0..counts.len())
                .flat_map(|k| samples.iter().map(move |&z| centre((k, z))))
                .collect();
            let terms = curtain.terms(&sampled);
            let mut exact = Vec::new();
            for (k, (column, terms)) in columns
                .chunks_mut(nz)
                .zip(terms.chunks_exact(samples.len()))
                .enumerate()
            {
                let counts = &counts[k];
                for (&z, &b) in samples.iter().zip(terms) {
                    column[z] = counts[z] + b >= 0.5;
                }
                for s in 1..samples.len() {
                    let (z0, z1, b0, b1) = (samples[s - 1], samples[s], terms[s - 1], terms[s]);
                    let smooth = (b1 - b0).abs() < MAX_STEP;
                    for z in z0 + 1..z1 {
                        let estimate = counts[z] + b0 + (b1 - b0) * (z - z0) as f64 / (z1 - z0) as f64;
                        if smooth && (estimate - 0.5).abs() > MARGIN {
                            column[z] = estimate >= 0.5;
                        } else {
                            exact.push((k, z));
                        }
                    }
                }
            }
            let terms = curtain.terms(&exact.iter().copied().map(centre).collect::<Vec<_>>());
            for (&(k, z), &b) in exact.iter().zip(&terms) {
                columns[k * nz + z] = counts[k][z] + b >= 0.5;
            }
        });
    inside
}

/// Columns whose points go through the curtain's edges together: more lanes of work an edge.
const COLUMNS_TOGETHER: usize = 8;

/// The solid angle of the triangle (a, b, c) seen from the origin (Van Oosterom & Strackee),
/// positive when the triangle winds counter-clockwise as seen from the origin's far side.
pub fn solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let half = half_solid_angle(a, b, c);
    2.0 * half.y.atan2(half.x)
}

/// A complex number whose argument is half of [`solid_angle`]: (denominator, numerator).
fn half_solid_angle(a: DVec3, b: DVec3, c: DVec3) -> DVec2 {
    half_solid_angle_of([a, b, c], [a.length(), b.length(), c.length()])
}

/// [`half_solid_angle`] of the corners with their lengths given.
#[inline(always)]
fn half_solid_angle_of([a, b, c]: [DVec3; 3], [la, lb, lc]: [f64; 3]) -> DVec2 {
    let numerator = a.dot(b.cross(c));
    let denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    DVec2::new(denominator, numerator)
}

/// [`half_solid_angle_of`] with the third corner straight down, (0, 0, -1), at length 1: its
/// multiplications by 0 and 1 left out, which only ever add a zero, so the same value for finite
/// corners (up to the sign of a zero, which no comparison reads).
#[inline(always)]
fn half_solid_angle_down(a: DVec3, b: DVec3, [la, lb]: [f64; 2]) -> DVec2 {
    let numerator = a.y * b.x - a.x * b.y;
    let denominator = la * lb + a.dot(b) - a.z * lb - b.z * la;
    DVec2::new(denominator, numerator)
}

/// The open boundary as the curtain term reads it: each edge's ends index the boundary's own
/// vertices, so that a point's distance to a vertex two edges share is taken once.
pub struct Curtain {
    vertices: Vec<DVec3>,
    /// (start, end, weight): an edge taken `weight` times, backwards where negative.
    edges: Vec<(usize, usize, i32)>,
}

impl Curtain {
    pub fn new(mesh: &Mesh, boundary: &[BoundaryEdge]) -> Curtain {
        let mut slot = HashMap::new();
        let mut vertices = Vec::new();
        let mut index = |v: u32| {
            *slot.entry(v).or_insert_with(|| {
                vertices.push(mesh.positions[v as usize].as_dvec3());
                vertices.len() - 1
            })
        };
        let edges = boundary.iter().map(|e| (index(e.a), index(e.b), e.weight)).collect();
        Curtain { vertices, edges }
    }

    /// The curtain's share of w(p), from the open boundary alone.
    pub fn term(&self, p: DVec3) -> f64 {
        self.terms(&[p])[0]
    }

    /// [`Curtain::term`] at each of `points`.
    ///
    /// The sum of the edges' half solid angles is the argument of the product of their complex
    /// numbers, plus the whole turns it made: one atan2 a point instead of one an edge. Edge by
    /// edge, the points' products grow side by side, none waiting on the last multiplication,
    /// without a branch, so that the points go through in vector lanes.
    pub fn terms(&self, points: &[DVec3]) -> Vec<f64> {
        self.terms_by(points, Curtain::add_edges_fast)
    }

    /// [`Curtain::terms`], the edges added by `add_edges`.
    fn terms_by(&self, points: &[DVec3], add_edges: impl Fn(&Self, &mut Angles)) -> Vec<f64> {
        if points.is_empty() {
            return Vec::new();
        }
        let mut angles = Angles::new(points);
        add_edges(self, &mut angles);
        // Ω = 2·(half angles), w = Ω / 4π.
        angles.radians().map(|radians| radians / PI * 0.5).collect()
    }

    /// [`Curtain::add_edges`] in AVX2's wider vector lanes where the CPU has them: the same
    /// operations, so the same values to the bit.
    fn add_edges_fast(&self, angles: &mut Angles) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2.
            return unsafe { self.add_edges_avx2(angles) };
        }
        self.add_edges(angles)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn add_edges_avx2(&self, angles: &mut Angles) {
        self.add_edges(angles)
    }

    /// Adds each edge's half solid angle to `angles`, each vertex's distances from the points
    /// found first (a row a vertex).
    #[inline(always)]
    fn add_edges(&self, angles: &mut Angles) {
        let n = angles.turns.len();
        let [px, py, pz] = angles.at.each_ref().map(|c| &c[..n]);
        let mut distances = vec![0.0; self.vertices.len() * n];
        for (&v, row) in self.vertices.iter().zip(distances.chunks_exact_mut(n)) {
            for (k, distance) in row.iter_mut().enumerate() {
                *distance = (v - DVec3::new(px[k], py[k], pz[k])).length();
            }
        }
        for &(a, b, weight) in &self.edges {
            let lengths = [&distances[a * n..][..n], &distances[b * n..][..n]];
            for _ in 0..weight.unsigned_abs() {
                angles.add_edge([self.vertices[a], self.vertices[b]], lengths, weight < 0);
            }
        }
    }
}

/// Per point, a sum of arguments of complex numbers, kept as their product and the whole turns
/// it made; points in flat arrays, one a lane.
struct Angles {
    /// The points, one coordinate an array.
    at: [Vec<f64>; 3],
    product: [Vec<f64>; 2],
    turns: Vec<i64>,
}

impl Angles {
    fn new(points: &[DVec3]) -> Angles {
        Angles {
            at: std::array::from_fn(|k| points.iter().map(|p| p[k]).collect()),
            product: [vec![1.0; points.len()], vec![0.0; points.len()]],
            turns: vec![0; points.len()],
        }
    }

    /// Adds to each point's sum the argument of the half solid angle of the edge `ends` and
    /// the direction straight down, backwards where `backwards`, given the ends' `lengths` from
    /// each point, in (-π, π] as atan2 gives it.
    #[inline(always)]
    fn add_edge(&mut self, ends: [DVec3; 2], lengths: [&[f64]; 2], backwards: bool) {
        let n = self.turns.len();
        let [px, py, pz] = self.at.each_ref().map(|c| &c[..n]);
        let [la, lb] = lengths.map(|l| &l[..n]);
        let [product_x, product_y] = self.product.each_mut().map(|c| &mut c[..n]);
        let turns = &mut self.turns[..n];
        let [va, vb] = ends;
        for k in 0..n {
            let point = DVec3::new(px[k], py[k], pz[k]);
            let half = half_solid_angle_down(va - point, vb - point, [la[k], lb[k]]);
            // An edge taken backwards turns the other way.
            let z = DVec2::new(half.x, if backwards { -half.y } else { half.y });
            let p = DVec2::new(product_x[k], product_y[k]);
            let mut q = DVec2::new(p.x * z.x - p.y * z.y, p.x * z.y + p.y * z.x);
            // Both arguments in [0, π] and the product's below: the sum passed π. Both in
            // (-π, 0) and the product's in [0, π]: it reached -π. Otherwise their sum is the
            // product's. The product's own sign decides, so a sum that rounds across π stays
            // consistent.
            q.y += 0.0; // -0 as +0: the upper half plane, as atan2 reads it
            let passed = p.y >= 0.0 && z.y >= 0.0 && q.y < 0.0;
            let reached = p.y < 0.0 && z.y < 0.0 && q.y >= 0.0;
            // Scaled by a power of two, exactly, to [1, 2) in its larger part, so that the
            // product neither overflows nor vanishes: the exponent's bits give the power.
            let exponent = (q.x.abs().max(q.y.abs()).to_bits() >> 52) as i64;
            let q = q * f64::from_bits(((2046 - exponent).clamp(1, 2046) as u64) << 52);
            // atan2(0, 0) is 0: a zero adds nothing.
            let adds = z != DVec2::ZERO;
            product_x[k] = if adds { q.x } else { p.x };
            product_y[k] = if adds { q.y } else { p.y };
            turns[k] += i64::from(adds) * (i64::from(passed) - i64::from(reached));
        }
    }

    fn radians(&self) -> impl Iterator<Item = f64> + '_ {
        let [x, y] = &self.product;
        (x.iter().zip(y).zip(&self.turns)).map(|((&x, &y), &turns)| y.atan2(x) + std::f64::consts::TAU * turns as f64)
    }
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
    curtain: Curtain,
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
            curtain: Curtain::new(mesh, boundary),
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
        f64::from(self.crossings_above(p).0) + self.curtain.term(p)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_half_angle_with_a_corner_straight_down_is_the_general_ones() {
        let mut rng = fastrand::Rng::with_seed(7);
        // Small whole numbers too, so that products and sums come out zero.
        let mut coordinate = || match rng.u8(0..3) {
            0 => f64::from(rng.i8(-2..=2)),
            _ => rng.f64() * 4.0 - 2.0,
        };
        for _ in 0..100_000 {
            let [a, b] = [(); 2].map(|()| DVec3::new(coordinate(), coordinate(), coordinate()));
            let general = half_solid_angle_of([a, b, DVec3::NEG_Z], [a.length(), b.length(), 1.0]);
            assert_eq!(
                half_solid_angle_down(a, b, [a.length(), b.length()]),
                general,
                "{a} {b}"
            );
        }
    }

    /// `vertices` points in a cube of side 2 about the origin, and `edges` between them in every
    /// direction, some taken backwards or more than once.
    fn random_edges(rng: &mut fastrand::Rng, vertices: u32, edges: usize) -> (Mesh, Vec<BoundaryEdge>) {
        let mut mesh = Mesh::default();
        let mut point = || glam::Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
        mesh.positions = (0..vertices).map(|_| point()).collect();
        let boundary = (0..edges)
            .map(|k| BoundaryEdge {
                a: rng.u32(0..vertices),
                b: rng.u32(0..vertices),
                weight: [1, -1, 2, -3][k % 4],
            })
            .collect();
        (mesh, boundary)
    }

    #[test]
    fn the_boundary_term_is_the_sum_of_each_edges_solid_angle() {
        let mut rng = fastrand::Rng::with_seed(11);
        let (mesh, boundary) = random_edges(&mut rng, 300, 600);
        let curtain = Curtain::new(&mesh, &boundary);
        let mut turns = 0;
        for k in 0..500 {
            // Points among the edges, and on some of their ends.
            let p = match k % 10 {
                0 => mesh.positions[rng.usize(0..300)].as_dvec3(),
                _ => DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 3.0 - 1.5,
            };
            let one_by_one: f64 = boundary
                .iter()
                .map(|e| {
                    let a = mesh.positions[e.a as usize].as_dvec3() - p;
                    let b = mesh.positions[e.b as usize].as_dvec3() - p;
                    f64::from(e.weight) * solid_angle(a, b, DVec3::NEG_Z)
                })
                .sum::<f64>()
                / (4.0 * PI);
            let term = curtain.term(p);
            assert!(
                (term - one_by_one).abs() < 1e-9,
                "point {k}: {term} against {one_by_one}"
            );
            turns += usize::from(one_by_one.abs() > 1.0);
        }
        assert!(turns > 50, "{turns} points where the angles turn more than once");
    }

    #[test]
    fn points_summed_side_by_side_in_any_lanes_get_each_ones_own_term_to_the_bit() {
        let mut rng = fastrand::Rng::with_seed(23);
        let (mesh, boundary) = random_edges(&mut rng, 100, 200);
        let curtain = Curtain::new(&mesh, &boundary);
        // On ends of edges too, where a length is 0, and as many points as a column has, or
        // more than a vector holds.
        let points: Vec<DVec3> = (0..37)
            .map(|k| match k % 5 {
                0 => mesh.positions[rng.usize(0..100)].as_dvec3(),
                _ => DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 3.0 - 1.5,
            })
            .collect();
        let together = curtain.terms(&points);
        for (p, term) in points.iter().zip(&together) {
            assert_eq!(term.to_bits(), curtain.term(*p).to_bits());
        }
        // The portable lanes, against those `terms` chose.
        let portable = curtain.terms_by(&points, Curtain::add_edges);
        assert_eq!(portable.len(), points.len());
        assert!(portable.iter().zip(&together).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
