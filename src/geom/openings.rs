//! Openings narrower than `cook.smallest_hole`, closed, as Umbra's Smallest Hole does: what
//! shows only through them counts as hidden. Three kinds, found on the open boundary's loops:
//!
//! - a **hole**: a loop that fits in a ball of that diameter, capped by a fan from its centre;
//! - a **gap**: two loops each within that width of the other (a lid in its rim), joined by a
//!   band of triangles zipped along both;
//! - a **seam**: a loop lying within that width of another part of the mesh (a handle's end
//!   against a body), capped like a hole.
//!
//! Wider openings stay open, so a setting of 0 changes nothing.

use super::proximity::SurfaceIndex;
use crate::mesh::topology::{BoundaryEdge, components};
use crate::mesh::{Mesh, point_bounds};
use glam::DVec3;
use serde::Serialize;
use std::collections::HashMap;

/// An opening counted as closed.
#[derive(Clone, Debug, Serialize)]
pub struct Opening {
    /// `hole`, `gap` or `seam`.
    pub kind: &'static str,
    /// How wide it is: a hole's diameter, the distance across a gap, how far a seam's loop lies
    /// from the other part.
    pub width: f64,
    /// The centre of its loop (of both loops, for a gap).
    pub position: [f64; 3],
    /// Its loop or loops, for pictures.
    pub outline: Vec<Vec<[f64; 3]>>,
}

/// `mesh` with every opening narrower than `width` closed, and those openings. The added
/// triangles follow the loops' orientation, so a closed part comes out consistently oriented.
pub fn close_openings(mesh: &Mesh, boundary: &[BoundaryEdge], width: f64) -> (Mesh, Vec<Opening>) {
    let mut closed = mesh.clone();
    let mut openings = Vec::new();
    if width <= 0.0 || boundary.is_empty() {
        return (closed, openings);
    }
    let loops = boundary_loops(boundary);
    let point = |v: u32| mesh.positions[v as usize].as_dvec3();
    let points: Vec<Vec<DVec3>> = loops.iter().map(|l| l.iter().map(|&v| point(v)).collect()).collect();
    let mut done = vec![false; loops.len()];
    for (i, loop_points) in points.iter().enumerate() {
        let diameter = diameter(loop_points);
        if diameter < width {
            cap(&mut closed, &loops[i], loop_points);
            openings.push(opening("hole", diameter, &[loop_points]));
            done[i] = true;
        }
    }
    for i in 0..loops.len() {
        for j in i + 1..loops.len() {
            if done[i] || done[j] {
                continue;
            }
            let across = hausdorff(&points[i], &points[j]);
            if across < width {
                band(&mut closed, &loops[i], &loops[j], &points[i], &points[j]);
                openings.push(opening("gap", across, &[&points[i], &points[j]]));
                done[i] = true;
                done[j] = true;
            }
        }
    }
    let component = components(mesh);
    let index = SurfaceIndex::new(mesh, width);
    for (i, loop_points) in points.iter().enumerate().filter(|&(i, _)| !done[i]) {
        let own = component[loops[i][0] as usize];
        let apart = |p: DVec3| index.nearest_where(p, |t| component[mesh.triangles[t][0] as usize] != own);
        let far = loop_points
            .iter()
            .map(|&p| apart(p))
            .try_fold(0.0f64, |far, d| d.map(|d| far.max(d)));
        if let Some(far) = far.filter(|&far| far < width) {
            cap(&mut closed, &loops[i], loop_points);
            openings.push(opening("seam", far, &[loop_points]));
        }
    }
    (closed, openings)
}

fn opening(kind: &'static str, width: f64, loops: &[&Vec<DVec3>]) -> Opening {
    let all: Vec<DVec3> = loops.iter().flat_map(|l| l.iter().copied()).collect();
    let (lo, hi) = point_bounds(all.iter().copied());
    Opening {
        kind,
        width,
        position: ((lo + hi) * 0.5).to_array(),
        outline: loops.iter().map(|l| l.iter().map(|p| p.to_array()).collect()).collect(),
    }
}

/// The boundary's closed loops of vertices, each in the direction of its edges (an edge of
/// weight -w is w copies of b → a). Chains that do not close are left out.
pub fn boundary_loops(boundary: &[BoundaryEdge]) -> Vec<Vec<u32>> {
    let mut next: HashMap<u32, Vec<u32>> = HashMap::new();
    for e in boundary {
        let (a, b) = if e.weight > 0 { (e.a, e.b) } else { (e.b, e.a) };
        for _ in 0..e.weight.unsigned_abs() {
            next.entry(a).or_default().push(b);
        }
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut loops = Vec::new();
    for start in starts {
        while let Some(mut at) = next.get_mut(&start).and_then(Vec::pop) {
            let mut chain = vec![start];
            while at != start {
                chain.push(at);
                match next.get_mut(&at).and_then(Vec::pop) {
                    Some(to) => at = to,
                    None => break,
                }
            }
            if at == start && chain.len() >= 3 {
                loops.push(chain);
            }
        }
    }
    loops
}

/// The largest distance between two points of a loop.
fn diameter(points: &[DVec3]) -> f64 {
    let mut far = 0.0f64;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            far = far.max(a.distance(*b));
        }
    }
    far
}

/// How far the farthest point of either loop lies from the other loop's polyline.
fn hausdorff(a: &[DVec3], b: &[DVec3]) -> f64 {
    let one_way = |from: &[DVec3], to: &[DVec3]| {
        from.iter()
            .map(|&p| {
                (0..to.len())
                    .map(|k| distance_to_segment(p, to[k], to[(k + 1) % to.len()]))
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0f64, f64::max)
    };
    one_way(a, b).max(one_way(b, a))
}

fn distance_to_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 {
        ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}

/// A fan from the loop's centre; each edge a → b of the loop gets the triangle (b, a, centre).
fn cap(mesh: &mut Mesh, loop_vertices: &[u32], points: &[DVec3]) {
    let centre = points.iter().copied().sum::<DVec3>() / points.len() as f64;
    let c = mesh.positions.len() as u32;
    mesh.positions.push(centre.as_vec3());
    for k in 0..loop_vertices.len() {
        let (a, b) = (loop_vertices[k], loop_vertices[(k + 1) % loop_vertices.len()]);
        mesh.triangles.push([b, a, c]);
    }
}

/// Joins two boundary loops of `mesh` (as [`boundary_loops`] gives them) by a band.
pub fn join_loops(mesh: &mut Mesh, a: &[u32], b: &[u32]) {
    let point = |v: &u32| mesh.positions[*v as usize].as_dvec3();
    let (pa, pb): (Vec<DVec3>, Vec<DVec3>) = (a.iter().map(point).collect(), b.iter().map(point).collect());
    band(mesh, a, b, &pa, &pb);
}

/// Zips loop `a` to loop `b` from `b`'s point nearest `a`'s first, each step advancing along
/// the loop whose next diagonal is shorter. Two loops facing each other across a gap run in
/// opposite directions, and `b` is walked backwards; the band's triangles follow `a`.
fn band(mesh: &mut Mesh, a: &[u32], b: &[u32], pa: &[DVec3], pb: &[DVec3]) {
    let (n, m) = (a.len(), b.len());
    let nearest = (0..m)
        .min_by(|&x, &y| pa[0].distance(pb[x]).total_cmp(&pa[0].distance(pb[y])))
        .expect("a loop has points");
    // Loops turning the same way about the same axis run along each other.
    let turning = |p: &[DVec3]| (0..p.len()).map(|k| p[k].cross(p[(k + 1) % p.len()])).sum::<DVec3>();
    let along = turning(pa).dot(turning(pb)) > 0.0;
    let order: Vec<usize> = (0..m)
        .map(|k| {
            if along {
                (nearest + k) % m
            } else {
                (nearest + m - k) % m
            }
        })
        .collect();
    let (mut i, mut j) = (0, 0);
    while i < n || j < m {
        let advance_a = match (i < n, j < m) {
            (true, true) => {
                let (a1, b0) = (pa[(i + 1) % n], pb[order[j]]);
                let (a0, b1) = (pa[i], pb[order[(j + 1) % m]]);
                a1.distance(b0) <= a0.distance(b1)
            }
            (advance_a, _) => advance_a,
        };
        let (bj, ai) = (b[order[j % m]], a[i % n]);
        if advance_a {
            mesh.triangles.push([a[(i + 1) % n], ai, bj]);
            i += 1;
        } else {
            mesh.triangles.push([bj, b[order[(j + 1) % m]], ai]);
            j += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::orient_closed_components;
    use glam::Vec3;

    /// A box from `lo` to `hi` without its top (+y) face: one boundary loop of four corners.
    fn open_box(lo: Vec3, hi: Vec3) -> Mesh {
        let corner = |i: usize| Vec3::new([lo.x, hi.x][i & 1], [lo.y, hi.y][(i >> 1) & 1], [lo.z, hi.z][i >> 2]);
        let mut mesh = Mesh {
            positions: (0..8).map(corner).collect(),
            triangles: Vec::new(),
        };
        // Bottom, then the four sides, each a quad wound outwards.
        for [a, b, c, d] in [[0, 1, 5, 4], [0, 4, 6, 2], [1, 3, 7, 5], [0, 2, 3, 1], [4, 5, 7, 6]] {
            mesh.triangles.extend([[a, b, c], [a, c, d]]);
        }
        mesh
    }

    fn closes(mesh: &Mesh, width: f64) -> (Mesh, Vec<Opening>, crate::mesh::Topology) {
        let mut mesh = mesh.clone();
        let topology = orient_closed_components(&mut mesh);
        let (mut closed, openings) = close_openings(&mesh, &topology.boundary, width);
        let after = orient_closed_components(&mut closed);
        (closed, openings, after)
    }

    #[test]
    fn a_hole_narrower_than_the_width_is_capped_and_a_wider_one_stays() {
        let pot = open_box(Vec3::ZERO, Vec3::ONE);
        let (_, openings, after) = closes(&pot, 1.5);
        assert_eq!(openings.len(), 1);
        assert_eq!(openings[0].kind, "hole");
        assert!((openings[0].width - 2f64.sqrt()).abs() < 1e-6);
        assert_eq!((after.boundary_edges, after.closed_components), (0, 1));
        assert_eq!(after.inverted_components, 0, "the cap is wound as the box");
        let (closed, openings, after) = closes(&pot, 1.4);
        assert!(openings.is_empty());
        assert_eq!(closed.triangles.len(), pot.triangles.len());
        assert_eq!(after.boundary_edges, 4);
    }

    #[test]
    fn a_lid_in_its_rim_is_joined_by_a_band() {
        let mut pot = open_box(Vec3::ZERO, Vec3::new(2.0, 1.0, 2.0));
        // A lid 1.9 wide at the rim's height, facing up: a gap of 0.05 all round.
        let base = pot.positions.len() as u32;
        pot.positions.extend([
            Vec3::new(0.05, 1.0, 0.05),
            Vec3::new(1.95, 1.0, 0.05),
            Vec3::new(1.95, 1.0, 1.95),
            Vec3::new(0.05, 1.0, 1.95),
        ]);
        pot.triangles
            .extend([[base, base + 2, base + 1], [base, base + 3, base + 2]]);
        let (_, openings, after) = closes(&pot, 0.04);
        assert!(openings.is_empty(), "{openings:?}");
        assert_eq!(after.boundary_edges, 8);
        let (closed, openings, after) = closes(&pot, 0.1);
        assert_eq!(openings.len(), 1, "{openings:?}");
        assert_eq!(openings[0].kind, "gap");
        assert!((openings[0].width - 0.05 * 2f64.sqrt()).abs() < 1e-6, "{openings:?}");
        assert_eq!((after.boundary_edges, after.closed_components), (0, 1));
        assert_eq!(after.inverted_components, 0);
        assert!(
            closed
                .triangles
                .iter()
                .all(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        );
    }

    #[test]
    fn a_tube_standing_on_a_block_is_capped_where_it_stands() {
        let mut scene = open_box(Vec3::new(-2.0, -1.0, -2.0), Vec3::new(2.0, 0.0, 2.0));
        // Close the block: its top face.
        scene.triangles.extend([[2, 6, 7], [2, 7, 3]]);
        // A square tube from y = 0 to 1, open at both ends.
        let base = scene.positions.len() as u32;
        for y in [0.0, 1.0] {
            for (x, z) in [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
                scene.positions.push(Vec3::new(x, y, z));
            }
        }
        for k in 0..4 {
            let (a, b) = (base + k, base + (k + 1) % 4);
            scene.triangles.extend([[a, b, b + 4], [a, b + 4, a + 4]]);
        }
        let (_, openings, after) = closes(&scene, 0.1);
        assert_eq!(openings.len(), 1, "{openings:?}");
        assert_eq!(openings[0].kind, "seam");
        assert!(openings[0].width < 1e-9);
        assert_eq!(openings[0].position[1], 0.0, "the end on the block");
        assert_eq!(after.boundary_edges, 4, "the top end stays open");
    }

    #[test]
    fn width_zero_closes_nothing() {
        let pot = open_box(Vec3::ZERO, Vec3::ONE);
        let (closed, openings, _) = closes(&pot, 0.0);
        assert!(openings.is_empty());
        assert_eq!(closed.triangles, pot.triangles);
    }
}
