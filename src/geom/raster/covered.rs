//! The depth an occluder certainly puts in front of each pixel: pixels it covers whole, at the
//! farthest depth over the pixel. A pixel wholly inside one triangle is covered; so is one that
//! an edge between two triangles crosses, when the two lie on opposite sides of that edge on
//! screen and the pixel lies inside both triangles' other edges. Without the second rule every
//! wall split into triangles would show a line of open pixels along each diagonal.

use super::rasterize_inner;
use crate::geom::camera::View;
use crate::mesh::{Mesh, weld_positions};
use glam::{DVec2, DVec3};
use std::collections::HashMap;

/// Two triangles sharing an edge: the edge's ends `a`, `b` and the corners across it, `c` and
/// `d`, as positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgePair {
    a: DVec3,
    b: DVec3,
    c: DVec3,
    d: DVec3,
}

/// The mesh's triangles and the edges that exactly two of them share, corners joined where
/// their positions are equal (a soup of separate triangles shares edges too).
pub struct Occluder<'a> {
    mesh: &'a Mesh,
    pairs: Vec<EdgePair>,
}

impl<'a> Occluder<'a> {
    pub fn new(mesh: &'a Mesh) -> Occluder<'a> {
        let (_, id) = weld_positions(&mesh.positions);
        let mut by_edge: HashMap<(u32, u32), Vec<(usize, usize)>> = HashMap::with_capacity(mesh.triangles.len() * 2);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (id[tri[k] as usize], id[tri[(k + 1) % 3] as usize]);
                if a != b {
                    by_edge.entry((a.min(b), a.max(b))).or_default().push((t, k));
                }
            }
        }
        let corner = |t: usize, k: usize| mesh.positions[mesh.triangles[t][k % 3] as usize].as_dvec3();
        let mut pairs: Vec<EdgePair> = by_edge
            .into_values()
            .filter(|sharing| sharing.len() == 2)
            .map(|sharing| {
                let ((t, k), (u, m)) = (sharing[0], sharing[1]);
                EdgePair {
                    a: corner(t, k),
                    b: corner(t, k + 1),
                    c: corner(t, k + 2),
                    d: corner(u, m + 2),
                }
            })
            .collect();
        // Hash order would make the f32 minimum below depend on it only through ties; sort for
        // a stable report anyway.
        pairs.sort_by(|p, q| {
            p.a.to_array()
                .partial_cmp(&q.a.to_array())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        Occluder { mesh, pairs }
    }

    /// Per pixel of `view`, the nearest of the farthest depths over the pixel of what covers it
    /// whole; `f32::INFINITY` where nothing does.
    pub fn depth(&self, view: &View) -> Vec<f32> {
        let n = view.pixels;
        let mut depth = vec![f32::INFINITY; n * n];
        for tri in self.mesh.triangles_f64() {
            rasterize_inner(view, &tri, |i, d| depth[i] = depth[i].min(d as f32));
        }
        for pair in &self.pairs {
            across(view, pair, |i, d| depth[i] = depth[i].min(d as f32));
        }
        depth
    }
}

/// Visits the pixels an edge between two triangles crosses that the two cover together, with
/// the farther of the two planes' farthest depths over the pixel.
fn across(view: &View, pair: &EdgePair, mut visit: impl FnMut(usize, f64)) {
    let near = view.depth_tolerance();
    let p = [pair.a, pair.b, pair.c, pair.d].map(|v| view.project(v));
    if p.iter().any(|q| !q.is_finite() || q.z <= near) {
        return;
    }
    let s = p.map(|q| q.truncate());
    let [a, b, c, d] = s;
    let side = |from: DVec2, to: DVec2, q: DVec2| cross(to - from, q - from);
    // On screen, c and d on opposite sides of a–b: else the edge is a fold, where the pair
    // covers only one side.
    if side(a, b, c) * side(a, b, d) >= 0.0 {
        return;
    }
    // Each of the four outer edges, oriented so that the pair lies on its positive side.
    let edges: Vec<(DVec2, DVec2)> = [(c, a, b), (c, b, a), (d, a, b), (d, b, a)]
        .into_iter()
        .map(|(apex, end, other)| {
            if side(apex, end, other) >= 0.0 {
                (apex, end)
            } else {
                (end, apex)
            }
        })
        .collect();
    // Where the pair's two planes are at screen point q: depth is 1 / w, w linear on screen.
    let plane = |t: [usize; 3]| {
        let (q0, q1, q2) = (s[t[0]], s[t[1]], s[t[2]]);
        let w = t.map(|k| 1.0 / p[k].z);
        let area = cross(q1 - q0, q2 - q0);
        move |q: DVec2| {
            let l1 = cross(q2 - q0, q - q0) / -area;
            let l2 = cross(q1 - q0, q - q0) / area;
            w[0] + (w[1] - w[0]) * l1 + (w[2] - w[0]) * l2
        }
    };
    let (w_c, w_d) = (plane([0, 1, 2]), plane([0, 1, 3]));
    let lo = a.min(b).min(c).min(d);
    let hi = a.max(b).max(c).max(d);
    let n = view.pixels as f64;
    let (x0, x1) = (lo.x.floor().max(0.0), (hi.x.ceil() - 1.0).min(n - 1.0));
    let (y0, y1) = (lo.y.floor().max(0.0), (hi.y.ceil() - 1.0).min(n - 1.0));
    if !(x0 <= x1 && y0 <= y1) {
        return;
    }
    for y in y0 as usize..=y1 as usize {
        for x in x0 as usize..=x1 as usize {
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                .map(|(dx, dy)| DVec2::new(x as f64 + dx, y as f64 + dy));
            let inside = corners
                .iter()
                .all(|&q| edges.iter().all(|&(from, to)| side(from, to, q) >= 0.0));
            if !inside {
                continue;
            }
            let w = corners
                .iter()
                .flat_map(|&q| [w_c(q), w_d(q)])
                .fold(f64::INFINITY, f64::min);
            if w > 0.0 {
                visit(y * view.pixels + x, 1.0 / w);
            }
        }
    }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A square wall at z = -5 in front of a camera at the origin, split along a diagonal.
    fn wall() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(-2.0, -2.0, -5.0),
                Vec3::new(2.0, -2.0, -5.0),
                Vec3::new(2.0, 2.0, -5.0),
                Vec3::new(-2.0, 2.0, -5.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    #[test]
    fn a_split_wall_covers_its_diagonal() {
        let view = View::perspective(DVec3::ZERO, DVec3::Z, 64, 1e-3);
        let mesh = wall();
        let mut alone = vec![f32::INFINITY; 64 * 64];
        for tri in mesh.triangles_f64() {
            rasterize_inner(&view, &tri, |i, d| alone[i] = alone[i].min(d as f32));
        }
        let covered = Occluder::new(&mesh).depth(&view);
        let count = |d: &[f32]| d.iter().filter(|v| v.is_finite()).count();
        // The wall spans x and y over 0.4 of the half screen each way: 19.2 to 44.8, so pixels
        // 20 to 43, 24 by 24, all covered once the diagonal is.
        assert_eq!(count(&covered), 24 * 24);
        assert!(count(&alone) < 24 * 24 - 20, "{} without the pair rule", count(&alone));
        assert!(
            covered
                .iter()
                .filter(|v| v.is_finite())
                .all(|&d| (d - 5.0).abs() < 1e-4)
        );
    }

    #[test]
    fn a_fold_covers_only_what_each_triangle_does() {
        // The second triangle folded back over the first: together they cover no more.
        let mut mesh = wall();
        mesh.positions[3] = Vec3::new(1.9, -1.9, -4.0);
        let view = View::perspective(DVec3::ZERO, DVec3::Z, 64, 1e-3);
        let mut alone = vec![f32::INFINITY; 64 * 64];
        for tri in mesh.triangles_f64() {
            rasterize_inner(&view, &tri, |i, d| alone[i] = alone[i].min(d as f32));
        }
        assert_eq!(Occluder::new(&mesh).depth(&view), alone);
    }
}
