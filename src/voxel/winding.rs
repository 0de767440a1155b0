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

mod far_field;
pub mod gpu;

use super::{Grid, columns::ColumnCrossings, columns::ColumnIndex, columns::column_hit};
use crate::mesh::{BoundaryEdge, Mesh, point_bounds};
use far_field::FarField;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::OnceLock;

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
///
/// Most columns are settled by [`Curtain::bounded_terms`]: each decision there is the exact
/// terms' wherever the bound leaves no doubt, and the rest are made on exact terms, so the
/// voxels are those of exact terms alone.
pub fn classify(crossings: &ColumnCrossings, mesh: &Mesh, boundary: &[BoundaryEdge], grid: &Grid) -> Vec<bool> {
    classify_by(crossings, mesh, boundary, grid, Curtain::bounded_terms)
}

/// [`classify`] with the bounded terms from `bounded_terms`.
fn classify_by(
    crossings: &ColumnCrossings,
    mesh: &Mesh,
    boundary: &[BoundaryEdge],
    grid: &Grid,
    bounded_terms: impl Fn(&Curtain, &[DVec3]) -> (Vec<f64>, Vec<f64>) + Sync,
) -> Vec<bool> {
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
    let zero_bounds = vec![0.0; samples.len()];
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
            // Each column settled by the bounded terms where they settle every decision, else
            // by the exact ones.
            let (terms, bounds) = bounded_terms(&curtain, &sampled);
            let (mut exact, mut unsettled) = (Vec::new(), Vec::new());
            for (k, column) in columns.chunks_mut(nz).enumerate() {
                let at = k * samples.len()..(k + 1) * samples.len();
                let (terms, bounds) = (&terms[at.clone()], &bounds[at]);
                let left = settle_column(column, &counts[k], &samples, terms, bounds);
                match left {
                    Some(left) => exact.extend(left.into_iter().map(|z| (k, z))),
                    None => unsettled.push(k),
                }
            }
            let points = |&k: &usize| samples.iter().map(move |&z| centre((k, z)));
            let terms = curtain.terms(&unsettled.iter().flat_map(points).collect::<Vec<_>>());
            for (&k, terms) in unsettled.iter().zip(terms.chunks_exact(samples.len())) {
                let column = &mut columns[k * nz..(k + 1) * nz];
                let left = settle_column(column, &counts[k], &samples, terms, &zero_bounds);
                exact.extend(
                    left.expect("exact terms settle every decision")
                        .into_iter()
                        .map(|z| (k, z)),
                );
            }
            // The voxels left to their own terms: bounded first, then exact where the bound
            // leaves them open.
            let (terms, bounds) = bounded_terms(&curtain, &exact.iter().copied().map(centre).collect::<Vec<_>>());
            let mut open = Vec::new();
            for (&(k, z), (&b, &bound)) in exact.iter().zip(terms.iter().zip(&bounds)) {
                match at_least(counts[k][z] + b, 0.5, bound) {
                    Some(inside) => columns[k * nz + z] = inside,
                    None => open.push((k, z)),
                }
            }
            let terms = curtain.terms(&open.iter().copied().map(centre).collect::<Vec<_>>());
            for (&(k, z), &b) in open.iter().zip(&terms) {
                columns[k * nz + z] = counts[k][z] + b >= 0.5;
            }
        });
    inside
}

/// Decides a column's voxels from the curtain term at `samples` (`terms`, each within its
/// bound of the exact term): each sample by its own term, the voxels between by interpolation
/// where the term changes slowly and the estimate lies clear of the threshold. Returns the
/// voxels left to their own terms, or None where a bound leaves a decision open; with every
/// bound 0, every decision is the exact terms' and none is left open.
fn settle_column(
    column: &mut [bool],
    counts: &[f64],
    samples: &[usize],
    terms: &[f64],
    bounds: &[f64],
) -> Option<Vec<usize>> {
    let mut left = Vec::new();
    for ((&z, &b), &bound) in samples.iter().zip(terms).zip(bounds) {
        column[z] = at_least(counts[z] + b, 0.5, bound)?;
    }
    for s in 1..samples.len() {
        let (z0, z1, b0, b1) = (samples[s - 1], samples[s], terms[s - 1], terms[s]);
        let smooth = !at_least((b1 - b0).abs(), MAX_STEP, bounds[s - 1] + bounds[s])?;
        // The estimate weighs the two samples' terms, so it is off by no more than either.
        let bound = bounds[s - 1].max(bounds[s]);
        for z in z0 + 1..z1 {
            let estimate = counts[z] + b0 + (b1 - b0) * (z - z0) as f64 / (z1 - z0) as f64;
            if smooth && !at_least(MARGIN, (estimate - 0.5).abs(), bound)? {
                column[z] = at_least(estimate, 0.5, bound)?;
            } else {
                left.push(z);
            }
        }
    }
    Some(left)
}

/// Whether x ≥ t, for every value within `bound` of x: None where the bound leaves it open.
/// With a bound of 0, x ≥ t.
fn at_least(x: f64, t: f64, bound: f64) -> Option<bool> {
    match bound {
        0.0 => Some(x >= t),
        _ if x - bound >= t => Some(true),
        _ if x + bound < t => Some(false),
        _ => None,
    }
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
    /// Built by the first [`Curtain::bounded_terms`]: the winding field never asks.
    far_field: OnceLock<FarField>,
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
        Curtain {
            vertices,
            edges,
            far_field: OnceLock::new(),
        }
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
        self.terms_by(points, add_edges_fast)
    }

    /// [`Curtain::terms`], the edges added by `add_edges`.
    fn terms_by(
        &self,
        points: &[DVec3],
        add_edges: impl Fn(&[DVec3], &[(usize, usize, i32)], &mut Angles),
    ) -> Vec<f64> {
        if points.is_empty() {
            return Vec::new();
        }
        let mut angles = Angles::new(points);
        add_edges(&self.vertices, &self.edges, &mut angles);
        angles.terms().collect()
    }

    /// [`Curtain::terms`] near enough, each with a bound on how far it may be from it: loops
    /// of edges far from all the points count as dipoles (`far_field`), the rest exactly.
    /// The bound takes in a billionth for rounding, far more than the exact sum's own.
    pub fn bounded_terms(&self, points: &[DVec3]) -> (Vec<f64>, Vec<f64>) {
        let far_field = self
            .far_field
            .get_or_init(|| FarField::new(&self.vertices, &self.edges));
        let (mut terms, mut bounds) = (vec![0.0; points.len()], vec![ROUNDING; points.len()]);
        // In groups of points at about one height: the nearer the points lie to each other,
        // the more loops are far from them all.
        let mut order: Vec<usize> = (0..points.len()).collect();
        order.sort_by(|&a, &b| points[a].z.total_cmp(&points[b].z));
        for group in order.chunks(BOUNDED_GROUP) {
            let points: Vec<DVec3> = group.iter().map(|&i| points[i]).collect();
            let (lo, hi) = point_bounds(points.iter().copied());
            let split = far_field.split(lo, hi);
            let mut angles = Angles::new(&points);
            add_edges_fast(&split.near_vertices, &split.near_edges, &mut angles);
            let mut near: Vec<f64> = angles.terms().collect();
            let mut far = vec![ROUNDING; points.len()];
            far_field.add_far(&split, &points, &mut near, &mut far);
            for ((&i, term), bound) in group.iter().zip(near).zip(far) {
                (terms[i], bounds[i]) = (term, bound);
            }
        }
        (terms, bounds)
    }
}

/// Points whose bounded curtain terms are found together.
const BOUNDED_GROUP: usize = 64;

/// What [`Curtain::bounded_terms`] allows for rounding.
const ROUNDING: f64 = 1e-9;

/// [`add_edges`] in AVX2's wider vector lanes where the CPU has them: the same operations, so
/// the same values to the bit.
fn add_edges_fast(vertices: &[DVec3], edges: &[(usize, usize, i32)], angles: &mut Angles) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { add_edges_avx2(vertices, edges, angles) };
    }
    add_edges(vertices, edges, angles)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn add_edges_avx2(vertices: &[DVec3], edges: &[(usize, usize, i32)], angles: &mut Angles) {
    add_edges(vertices, edges, angles)
}

/// Adds each edge's half solid angle to `angles` (an edge's ends index `vertices`, its weight
/// says how many times, backwards where negative), each vertex's distances from the points
/// found first (a row a vertex).
#[inline(always)]
fn add_edges(vertices: &[DVec3], edges: &[(usize, usize, i32)], angles: &mut Angles) {
    let n = angles.turns.len();
    let [px, py, pz] = angles.at.each_ref().map(|c| &c[..n]);
    let mut distances = vec![0.0; vertices.len() * n];
    for (&v, row) in vertices.iter().zip(distances.chunks_exact_mut(n)) {
        for (k, distance) in row.iter_mut().enumerate() {
            *distance = (v - DVec3::new(px[k], py[k], pz[k])).length();
        }
    }
    for &(a, b, weight) in edges {
        let lengths = [&distances[a * n..][..n], &distances[b * n..][..n]];
        for _ in 0..weight.unsigned_abs() {
            angles.add_edge([vertices[a], vertices[b]], lengths, weight < 0);
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

    /// Each point's curtain term: Ω = 2·(half angles), w = Ω / 4π.
    fn terms(&self) -> impl Iterator<Item = f64> + '_ {
        let [x, y] = &self.product;
        (x.iter().zip(y).zip(&self.turns))
            .map(|((&x, &y), &turns)| (y.atan2(x) + std::f64::consts::TAU * turns as f64) / PI * 0.5)
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
    columns: ColumnIndex,
}

impl<'a> WindingField<'a> {
    pub fn new(mesh: &'a Mesh, boundary: &'a [BoundaryEdge]) -> WindingField<'a> {
        WindingField {
            mesh,
            curtain: Curtain::new(mesh, boundary),
            columns: ColumnIndex::new(mesh),
        }
    }

    /// The triangles whose footprint buckets meet the xy box [lo, hi]: a superset of those
    /// that reach into it, sorted.
    pub fn triangles_over(&self, lo: DVec2, hi: DVec2) -> Vec<u32> {
        self.columns.triangles_over(lo, hi)
    }

    pub fn winding(&self, p: DVec3) -> f64 {
        f64::from(self.crossings_above(p).0) + self.curtain.term(p)
    }

    /// w near enough at each of `points`, each with a bound on how far it may be from
    /// [`WindingField::winding`]: for many points, far faster ([`Curtain::bounded_terms`]).
    pub fn bounded_windings(&self, points: &[DVec3]) -> Vec<(f64, f64)> {
        let (terms, bounds) = self.curtain.bounded_terms(points);
        points
            .iter()
            .zip(terms)
            .zip(bounds)
            .map(|((&p, term), bound)| (f64::from(self.crossings_above(p).0) + term, bound))
            .collect()
    }

    /// The crossings of the upward ray from `p`: (signed sum, count). On a closed surface the
    /// sum is w(p) and the count's parity is the parity test.
    pub fn crossings_above(&self, p: DVec3) -> (i32, u32) {
        let (mut sum, mut count) = (0i32, 0u32);
        for &t in self.columns.triangles_at(p) {
            let tri = self.mesh.corners(t as usize).map(|v| v.as_dvec3().to_array());
            if let Some(hit) = column_hit(&tri, [p.x, p.y])
                && hit.z > p.z
            {
                sum += i32::from(hit.sign);
                count += 1;
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
        let portable = curtain.terms_by(&points, add_edges);
        assert_eq!(portable.len(), points.len());
        assert!(portable.iter().zip(&together).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// `count` small loops of edges (bent polygons, some wound backwards, some taken twice)
    /// over a wide box, as a mesh's boundary.
    fn scattered_loops(rng: &mut fastrand::Rng, count: usize) -> (Mesh, Vec<BoundaryEdge>) {
        let mut mesh = Mesh::default();
        let mut boundary = Vec::new();
        for l in 0..count {
            let centre = glam::Vec3::new(rng.f32() * 100.0, rng.f32() * 100.0, rng.f32() * 10.0);
            let (sides, size) = (3 + rng.u32(0..6), 0.2 + rng.f32());
            let first = mesh.positions.len() as u32;
            for k in 0..sides {
                let angle = std::f32::consts::TAU * k as f32 / sides as f32;
                let bend = (rng.f32() - 0.5) * size;
                let rim = glam::Vec3::new(angle.cos(), 0.7 * angle.sin(), 0.3 * angle.sin() + bend);
                mesh.positions.push(centre + size * rim);
            }
            let weight = [1, -1, 2][l % 3];
            boundary.extend((0..sides).map(|k| BoundaryEdge {
                a: first + k,
                b: first + (k + 1) % sides,
                weight,
            }));
        }
        (mesh, boundary)
    }

    #[test]
    fn bounded_terms_lie_within_their_bounds_of_the_exact_terms() {
        let mut rng = fastrand::Rng::with_seed(31);
        // Clusters of points, some among the loops and on their vertices.
        let points = |rng: &mut fastrand::Rng, mesh: &Mesh| -> Vec<DVec3> {
            (0..40)
                .flat_map(|_| {
                    let at = DVec3::new(rng.f64() * 110.0 - 5.0, rng.f64() * 110.0 - 5.0, rng.f64() * 14.0 - 2.0);
                    let spread: Vec<DVec3> = (0..64)
                        .map(|k| match k % 16 {
                            0 => mesh.positions[rng.usize(0..mesh.positions.len())].as_dvec3(),
                            _ => at + DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 3.0,
                        })
                        .collect();
                    spread
                })
                .collect()
        };
        let (mesh, boundary) = scattered_loops(&mut rng, 400);
        let curtain = Curtain::new(&mesh, &boundary);
        let points = points(&mut rng, &mesh);
        let (terms, bounds) = curtain.bounded_terms(&points);
        let exact = curtain.terms(&points);
        let mut far = 0;
        for k in 0..points.len() {
            let off = (terms[k] - exact[k]).abs();
            assert!(
                off <= bounds[k],
                "point {k}: {} against {}, bound {}",
                terms[k],
                exact[k],
                bounds[k]
            );
            far += usize::from(bounds[k] > ROUNDING && bounds[k] < 0.01);
        }
        // The dipoles stand in for loops at most points, and their bounds settle decisions.
        assert!(far > points.len() / 2, "{far} of {} points", points.len());
        // Edges in no closed loop are always summed exactly.
        let (mesh, boundary) = random_edges(&mut rng, 100, 200);
        let curtain = Curtain::new(&mesh, &boundary);
        let points: Vec<DVec3> = (0..300)
            .map(|_| DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 30.0)
            .collect();
        let (terms, bounds) = curtain.bounded_terms(&points);
        for ((term, exact), bound) in terms.iter().zip(curtain.terms(&points)).zip(bounds) {
            assert_eq!(bound, ROUNDING);
            assert!((term - exact).abs() <= bound);
        }
    }

    #[test]
    fn voxels_settled_by_bounded_terms_are_those_of_exact_terms() {
        // A torus with many small holes, so that most loops are far from most columns.
        let mut mesh = crate::mesh::shapes::torus(10.0, 2.0, 120, 24);
        mesh.triangles = (0..mesh.triangles.len())
            .filter(|t| t % 14 > 1)
            .map(|t| mesh.triangles[t])
            .collect();
        let topology = crate::mesh::topology::orient_closed_components(&mut mesh);
        let (lo, hi) = mesh.bounds();
        let grid = Grid::fit(lo, hi, 48);
        let crossings = ColumnCrossings::build(&mesh, &grid);
        let boundary = &topology.boundary;
        let bounded = classify(&crossings, &mesh, boundary, &grid);
        let exact = classify_by(&crossings, &mesh, boundary, &grid, |curtain, points| {
            (curtain.terms(points), vec![0.0; points.len()])
        });
        assert_eq!(bounded, exact);
        assert!(exact.iter().any(|&v| v));
        // The bounded terms stood in for the exact ones.
        let curtain = Curtain::new(&mesh, boundary);
        let centres: Vec<DVec3> = (0..grid.dims[2]).map(|z| grid.center(20, 24, z)).collect();
        let (_, bounds) = curtain.bounded_terms(&centres);
        assert!(bounds.iter().all(|&b| b > ROUNDING && b < 0.05), "{bounds:?}");
    }
}
