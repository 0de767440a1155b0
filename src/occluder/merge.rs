//! The union of boxes as one watertight mesh, computed exactly on the grid that the boxes'
//! own coordinates span: boundary faces between filled and empty cells, coplanar faces merged
//! into rectangles, and every vertex that lies on a rectangle's edge made a vertex of that
//! rectangle too, so that no T-junction can open a crack.

use super::WorldBox;
use crate::mesh::Mesh;
use glam::Vec3;
use std::collections::HashMap;

/// A rectangle on the plane `axis = plane`, spanning cells [u0, u1) × [v0, v1) of the two other
/// axes (u = axis + 1, v = axis + 2, cyclically), facing +axis when `positive`.
struct Rect {
    axis: usize,
    plane: usize,
    u: [usize; 2],
    v: [usize; 2],
    positive: bool,
}

pub fn merge(boxes: &[WorldBox]) -> Mesh {
    Faces::of(boxes).mesh()
}

/// The triangles of [`merge`]'s mesh of `boxes`, without making it.
pub fn merged_triangles(boxes: &[WorldBox]) -> usize {
    Faces::of(boxes).triangles()
}

/// The boundary of a union of boxes as rectangles on the grid of the boxes' coordinates, with
/// every corner filed under the three axis-parallel lines through it.
struct Faces {
    rects: Vec<Rect>,
    coords: [Vec<f64>; 3],
    lines: HashMap<(usize, usize, usize), Vec<usize>>,
}

type Point = [usize; 3];

impl Faces {
    fn of(boxes: &[WorldBox]) -> Faces {
        let coords: [Vec<f64>; 3] = std::array::from_fn(|k| {
            let mut c: Vec<f64> = boxes.iter().flat_map(|b| [b.lo[k], b.hi[k]]).collect();
            c.sort_by(f64::total_cmp);
            c.dedup();
            c
        });
        // None without boxes.
        let cells = coords.clone().map(|c| c.len().saturating_sub(1));
        let cell_index = |c: [usize; 3]| (c[0] * cells[1] + c[1]) * cells[2] + c[2];
        let mut filled = vec![false; cells.iter().product()];
        for b in boxes {
            let lo: [usize; 3] = std::array::from_fn(|k| position(&coords[k], b.lo[k]));
            let hi: [usize; 3] = std::array::from_fn(|k| position(&coords[k], b.hi[k]));
            for x in lo[0]..hi[0] {
                for y in lo[1]..hi[1] {
                    for z in lo[2]..hi[2] {
                        filled[cell_index([x, y, z])] = true;
                    }
                }
            }
        }
        let is_filled = |c: [i64; 3]| {
            (0..3).all(|k| c[k] >= 0 && (c[k] as usize) < cells[k]) && filled[cell_index(c.map(|v| v as usize))]
        };
        let mut rects = Vec::new();
        for axis in 0..3 {
            let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
            let (nu, nv) = (cells[ua], cells[va]);
            for plane in 0..=cells[axis] {
                // +1: the face of a filled cell below the plane, -1: above it, 0: none.
                let mut facing = vec![0i8; nu * nv];
                for u in 0..nu {
                    for v in 0..nv {
                        let mut c = [0i64; 3];
                        c[ua] = u as i64;
                        c[va] = v as i64;
                        c[axis] = plane as i64 - 1;
                        let below = is_filled(c);
                        c[axis] = plane as i64;
                        let above = is_filled(c);
                        facing[u * nv + v] = i8::from(below) - i8::from(above);
                    }
                }
                merge_rectangles(&mut facing, nu, nv, |u, v, positive| {
                    rects.push(Rect {
                        axis,
                        plane,
                        u,
                        v,
                        positive,
                    })
                });
            }
        }
        let mut lines: HashMap<(usize, usize, usize), Vec<usize>> = HashMap::new();
        for r in &rects {
            for p in corners(r) {
                for axis in 0..3 {
                    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                    lines.entry((axis, p[a], p[b])).or_default().push(p[axis]);
                }
            }
        }
        for v in lines.values_mut() {
            v.sort_unstable();
            v.dedup();
        }
        Faces { rects, coords, lines }
    }

    /// Each rectangle's boundary polygon, with the corners of others that lie inside its edges.
    fn polygons(&self) -> impl Iterator<Item = Vec<Point>> + '_ {
        self.rects.iter().map(|r| {
            let ring = corners(r);
            let mut polygon: Vec<Point> = Vec::new();
            for k in 0..4 {
                let (a, b) = (ring[k], ring[(k + 1) % 4]);
                polygon.push(a);
                let axis = (0..3).find(|&i| a[i] != b[i]).expect("edges have length");
                let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
                let (lo, hi) = (a[axis].min(b[axis]), a[axis].max(b[axis]));
                let mut inner: Vec<usize> = self.lines[&(axis, a[o1], a[o2])]
                    .iter()
                    .copied()
                    .filter(|&c| c > lo && c < hi)
                    .collect();
                if a[axis] > b[axis] {
                    inner.reverse();
                }
                polygon.extend(inner.into_iter().map(|c| {
                    let mut p = a;
                    p[axis] = c;
                    p
                }));
            }
            polygon
        })
    }

    /// [`clip_ears`] makes n - 2 triangles of a polygon of n corners.
    fn triangles(&self) -> usize {
        self.polygons().map(|polygon| polygon.len() - 2).sum()
    }

    fn mesh(&self) -> Mesh {
        let mut mesh = Mesh::default();
        let mut index: HashMap<Point, u32> = HashMap::new();
        for polygon in self.polygons() {
            let ids: Vec<u32> = polygon
                .iter()
                .map(|&p| {
                    *index.entry(p).or_insert_with(|| {
                        mesh.positions.push(Vec3::new(
                            self.coords[0][p[0]] as f32,
                            self.coords[1][p[1]] as f32,
                            self.coords[2][p[2]] as f32,
                        ));
                        (mesh.positions.len() - 1) as u32
                    })
                })
                .collect();
            clip_ears(&polygon, &ids, &mut mesh.triangles);
        }
        mesh
    }
}

fn position(sorted: &[f64], value: f64) -> usize {
    sorted.partition_point(|&c| c < value)
}

/// Greedy rectangles over same-valued nonzero cells: extend along v, then along u.
fn merge_rectangles(facing: &mut [i8], nu: usize, nv: usize, mut emit: impl FnMut([usize; 2], [usize; 2], bool)) {
    for u0 in 0..nu {
        let mut v0 = 0;
        while v0 < nv {
            let s = facing[u0 * nv + v0];
            if s == 0 {
                v0 += 1;
                continue;
            }
            let mut v1 = v0 + 1;
            while v1 < nv && facing[u0 * nv + v1] == s {
                v1 += 1;
            }
            let mut u1 = u0 + 1;
            while u1 < nu && (v0..v1).all(|v| facing[u1 * nv + v] == s) {
                u1 += 1;
            }
            for u in u0..u1 {
                facing[u * nv + v0..u * nv + v1].fill(0);
            }
            emit([u0, u1], [v0, v1], s > 0);
            v0 = v1;
        }
    }
}

/// A rectangle's corners, counter-clockwise seen from the side it faces.
fn corners(r: &Rect) -> [Point; 4] {
    let (ua, va) = ((r.axis + 1) % 3, (r.axis + 2) % 3);
    let at = |u: usize, v: usize| {
        let mut p = [0; 3];
        p[r.axis] = r.plane;
        p[ua] = u;
        p[va] = v;
        p
    };
    // Counter-clockwise around +axis, since (axis, u, v) is right-handed.
    let ring = [
        at(r.u[0], r.v[0]),
        at(r.u[1], r.v[0]),
        at(r.u[1], r.v[1]),
        at(r.u[0], r.v[1]),
    ];
    if r.positive {
        ring
    } else {
        [ring[0], ring[3], ring[2], ring[1]]
    }
}

/// Triangulates a convex polygon whose edges may hold collinear vertices into n - 2
/// non-degenerate triangles, by clipping ears that are real corners and leave a polygon that
/// still has a corner (an ear whose diagonal runs along an edge would leave a flat remainder).
fn clip_ears(polygon: &[Point], ids: &[u32], out: &mut Vec<[u32; 3]>) {
    let collinear = |a: Point, b: Point, c: Point| {
        let d = |p: Point, q: Point| [0, 1, 2].map(|k| q[k] as i64 - p[k] as i64);
        let (u, v) = (d(a, b), d(a, c));
        u[1] * v[2] == u[2] * v[1] && u[2] * v[0] == u[0] * v[2] && u[0] * v[1] == u[1] * v[0]
    };
    let corner = |ring: &[usize], k: usize| {
        let n = ring.len();
        !collinear(
            polygon[ring[(k + n - 1) % n]],
            polygon[ring[k]],
            polygon[ring[(k + 1) % n]],
        )
    };
    let mut ring: Vec<usize> = (0..polygon.len()).collect();
    while ring.len() > 3 {
        let n = ring.len();
        let k = (0..n)
            .find(|&k| {
                let mut rest = ring.clone();
                rest.remove(k);
                corner(&ring, k) && (0..rest.len()).any(|j| corner(&rest, j))
            })
            .expect("a convex polygon has a clippable ear");
        out.push([ids[ring[(k + n - 1) % n]], ids[ring[k]], ids[ring[(k + 1) % n]]]);
        ring.remove(k);
    }
    out.push([ids[ring[0]], ids[ring[1]], ids[ring[2]]]);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_triangles_counted_are_those_of_the_merged_mesh() {
        assert_eq!(merged_triangles(&[]), 0);
        assert!(merge(&[]).triangles.is_empty());
        let mut rng = fastrand::Rng::with_seed(54);
        for _ in 0..300 {
            // Boxes on a coarse lattice, so that they touch, overlap and share faces: T-junctions.
            let boxes: Vec<WorldBox> = (0..rng.usize(1..7))
                .map(|_| {
                    let lo: [f64; 3] = std::array::from_fn(|_| rng.usize(0..5) as f64);
                    let hi: [f64; 3] = std::array::from_fn(|k| lo[k] + rng.usize(1..4) as f64);
                    WorldBox { lo, hi }
                })
                .collect();
            assert_eq!(merged_triangles(&boxes), merge(&boxes).triangles.len(), "{boxes:?}");
        }
    }
}
