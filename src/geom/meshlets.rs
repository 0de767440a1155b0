//! A mesh cut into meshlets: runs of at most [`MESHLET_TRIANGLES`] triangles in the Morton
//! order of their centroids, so near one another, each with its own vertices and bounds. A view
//! that needs only part of its image tests a meshlet's bounds once and skips it whole.

use crate::mesh::{Mesh, point_bounds};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Triangles in a meshlet, at most: few enough that its bounds stay tight, enough that testing
/// them costs far less than projecting its vertices.
pub const MESHLET_TRIANGLES: usize = 64;

pub struct Meshlet {
    /// Its triangles, in the mesh's order of corners, over its own vertices.
    pub mesh: Mesh,
    /// The bounds of its vertices.
    pub lo: DVec3,
    pub hi: DVec3,
}

impl Meshlet {
    /// The eight corners of its bounds.
    pub fn box_corners(&self) -> [DVec3; 8] {
        std::array::from_fn(|k| {
            DVec3::new(
                if k & 1 == 0 { self.lo.x } else { self.hi.x },
                if k & 2 == 0 { self.lo.y } else { self.hi.y },
                if k & 4 == 0 { self.lo.z } else { self.hi.z },
            )
        })
    }
}

/// `mesh`'s triangles as meshlets: together they hold each triangle once, with its corners.
pub fn meshlets(mesh: &Mesh) -> Vec<Meshlet> {
    let (lo, hi) = mesh.bounds();
    // 10 bits an axis, the same scale on each, so that the codes' cells are cubes.
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let key = |t: usize| {
        let centroid = mesh.corners(t).iter().sum::<Vec3>() / 3.0;
        let cell = ((centroid - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0));
        spread_bits(cell.x as u32) | spread_bits(cell.y as u32) << 1 | spread_bits(cell.z as u32) << 2
    };
    let mut order: Vec<(u32, u32)> = (0..mesh.triangles.len())
        .into_par_iter()
        .map(|t| (key(t), t as u32))
        .collect();
    order.par_sort_unstable();
    order
        .par_chunks(MESHLET_TRIANGLES)
        .map(|run| {
            let mut vertices: Vec<u32> = run.iter().flat_map(|&(_, t)| mesh.triangles[t as usize]).collect();
            vertices.sort_unstable();
            vertices.dedup();
            // Every corner is among the vertices just gathered.
            let local = |i: u32| vertices.binary_search(&i).unwrap_or_default() as u32;
            let triangles = run
                .iter()
                .map(|&(_, t)| mesh.triangles[t as usize].map(local))
                .collect();
            let positions: Vec<Vec3> = vertices.iter().map(|&i| mesh.positions[i as usize]).collect();
            let (lo, hi) = point_bounds(positions.iter().map(|p| p.as_dvec3()));
            Meshlet {
                mesh: Mesh { positions, triangles },
                lo,
                hi,
            }
        })
        .collect()
}

/// Whether the line from `p` along the unit vector `dir`, up to `reach`, crosses a triangle of
/// the meshlets: edges and corners count, with a billionth to spare, so that a line along a
/// seam between two triangles is not taken for clear.
pub fn line_blocked(meshlets: &[Meshlet], p: DVec3, dir: DVec3, reach: f64) -> bool {
    let inverse = dir.recip();
    meshlets.iter().any(|m| {
        // The slabs of its bounds, grown a little so that no line lies on one: the line meets
        // them, if at all, between `near` and `far`.
        let grow = DVec3::splat(1e-9 * (1.0 + m.lo.abs().max(m.hi.abs()).max_element()));
        let (a, b) = ((m.lo - grow - p) * inverse, (m.hi + grow - p) * inverse);
        let (near, far) = (a.min(b).max_element(), a.max(b).min_element());
        let misses = near > far || far < 0.0 || near > reach;
        !misses && (0..m.mesh.triangles.len()).any(|t| crosses(m.mesh.corners(t).map(|c| c.as_dvec3()), p, dir, reach))
    })
}

/// Whether the line from `p` along `dir`, beyond a billionth and short of `reach`, crosses
/// triangle `[a, b, c]` (Möller and Trumbore's test).
fn crosses([a, b, c]: [DVec3; 3], p: DVec3, dir: DVec3, reach: f64) -> bool {
    let (e1, e2) = (b - a, c - a);
    let h = dir.cross(e2);
    let det = e1.dot(h);
    if det.abs() < 1e-12 {
        return false;
    }
    let s = p - a;
    let u = s.dot(h) / det;
    let q = s.cross(e1);
    let v = dir.dot(q) / det;
    let t = e2.dot(q) / det;
    (-1e-9..=1.0 + 1e-9).contains(&u) && v >= -1e-9 && u + v <= 1.0 + 1e-9 && t > 1e-9 && t < reach
}

/// The low 10 bits of `v`, two zero bits after each: one axis of a Morton code.
fn spread_bits(v: u32) -> u32 {
    let mut v = v & 0x3ff;
    v = (v | v << 16) & 0x0300_00ff;
    v = (v | v << 8) & 0x0300_f00f;
    v = (v | v << 4) & 0x030c_30c3;
    (v | v << 2) & 0x0924_9249
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_is_blocked_by_a_triangle_it_crosses_within_its_reach() {
        let positions = (0..8).map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32));
        let triangles = crate::occluder::BOX_FACES
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]].map(|t| t.map(|i| i as u32)));
        let cube = meshlets(&Mesh {
            positions: positions.collect(),
            triangles: triangles.collect(),
        });
        let centre = DVec3::splat(0.5);
        for dir in [DVec3::X, DVec3::NEG_Y, DVec3::new(1.0, 1.0, 1.0).normalize()] {
            assert!(line_blocked(&cube, centre, dir, f64::INFINITY), "{dir}");
            assert!(!line_blocked(&cube, centre, dir, 0.4), "{dir} short of the wall");
            assert!(
                !line_blocked(&cube, centre + 2.0 * dir, dir, f64::INFINITY),
                "{dir} outside"
            );
        }
    }

    #[test]
    fn bits_spread_apart_by_two_zeros() {
        assert_eq!(spread_bits(0b1011), 0b001_000_001_001);
        assert_eq!(spread_bits(0x3ff), 0x0924_9249);
    }

    /// A flat grid of 24 × 16 squares in the xz-plane, its triangles in a scattered order.
    fn scattered_grid() -> Mesh {
        let positions = (0..25 * 17)
            .map(|k| Vec3::new((k % 25) as f32, 0.0, (k / 25) as f32))
            .collect();
        let squares = (0..24 * 16).map(|s| (s % 24 + (s / 24) * 25) as u32);
        let mut triangles: Vec<[u32; 3]> = squares
            .flat_map(|c| [[c, c + 1, c + 26], [c, c + 26, c + 25]])
            .collect();
        // 385 is prime to 768, the number of triangles: each lands once.
        let n = triangles.len();
        triangles = (0..n).map(|k| triangles[k * 385 % n]).collect();
        Mesh { positions, triangles }
    }

    fn footprint((lo, hi): (DVec3, DVec3)) -> f64 {
        (hi.x - lo.x) * (hi.z - lo.z)
    }

    #[test]
    fn meshlets_hold_every_triangle_once_with_its_corners_within_their_bounds() {
        let mesh = scattered_grid();
        let cut = meshlets(&mesh);
        assert_eq!(cut.len(), mesh.triangles.len().div_ceil(MESHLET_TRIANGLES));
        let key = |p: [Vec3; 3]| p.map(|c| c.to_array().map(f32::to_bits));
        let mut seen = Vec::new();
        for m in &cut {
            assert!(m.mesh.triangles.len() <= MESHLET_TRIANGLES);
            for t in 0..m.mesh.triangles.len() {
                let corners = m.mesh.corners(t);
                assert!(
                    corners
                        .iter()
                        .all(|p| p.as_dvec3().cmpge(m.lo).all() && p.as_dvec3().cmple(m.hi).all())
                );
                seen.push(key(corners));
            }
        }
        let mut all: Vec<_> = (0..mesh.triangles.len()).map(|t| key(mesh.corners(t))).collect();
        seen.sort_unstable();
        all.sort_unstable();
        assert_eq!(seen, all);
    }

    #[test]
    fn meshlets_gather_triangles_that_lie_near_one_another() {
        let mesh = scattered_grid();
        let ours: f64 = meshlets(&mesh).iter().map(|m| footprint((m.lo, m.hi))).sum();
        let in_file_order: f64 = mesh
            .triangles
            .chunks(MESHLET_TRIANGLES)
            .map(|run| {
                footprint(point_bounds(
                    run.iter().flatten().map(|&i| mesh.positions[i as usize].as_dvec3()),
                ))
            })
            .sum();
        // 384 squares in all, 32 to a meshlet. A run of a Morton order jumps now and then, so
        // its bounds may hold more than its own squares, but not much more.
        assert!(
            ours < 3.0 * 384.0 && ours < 0.5 * in_file_order,
            "{ours} against {in_file_order}"
        );
    }
}
