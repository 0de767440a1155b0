//! The sky views' band. Close the open surface with a curtain hanging straight down (−y) from
//! each boundary edge, and let W″(p) be the signed count of the surface's crossings on the ray
//! straight up from p: the winding number of the surface and the curtain, since that ray never
//! meets the curtain. A ray from p towards a sky view's camera rises or runs level, so it meets
//! the curtain only where p's image lies in the curtain's image, the band. Elsewhere W″ changes
//! along it only where it crosses the surface, and it is 0 at the camera: a point with W″ ≠ 0
//! whose image lies outside the band is hidden from that view.

use crate::geom::camera::View;
use crate::geom::clamped_index;
use crate::mesh::{BoundaryEdge, Mesh, point_bounds};
use crate::voxel::columns::{ColumnIndex, column_hit};
use glam::{DVec2, DVec3, Vec3};

/// The mesh with y and z swapped, bucketed by footprint: its vertical lines (along z) are the
/// original's lines straight up (along y).
pub struct UpColumns {
    swapped: Mesh,
    columns: ColumnIndex,
}

/// A point with y and z swapped.
fn swap(p: DVec3) -> DVec3 {
    DVec3::new(p.x, p.z, p.y)
}

impl UpColumns {
    pub fn new(mesh: &Mesh) -> UpColumns {
        let swapped = Mesh {
            positions: mesh.positions.iter().map(|p| Vec3::new(p.x, p.z, p.y)).collect(),
            triangles: mesh.triangles.clone(),
        };
        let columns = ColumnIndex::new(&swapped);
        UpColumns { swapped, columns }
    }

    /// W″(p): the signed count of the surface's crossings on the ray straight up from `p`,
    /// +1 where the surface faces up. Through an edge or a vertex each crossing counts once
    /// ([`column_hit`]'s tie-breaking).
    pub fn net_crossings_above(&self, p: DVec3) -> i32 {
        net_above(&self.crossings(p), p.y)
    }

    /// The surface's crossings of the vertical line through `p`: each one's height and sign,
    /// +1 where the surface faces up.
    pub fn crossings(&self, p: DVec3) -> Vec<(f64, i32)> {
        let q = swap(p);
        // The swap turns the triangles over, so each sign is negated back.
        self.columns
            .triangles_at(q)
            .iter()
            .filter_map(|&t| {
                let triangle = self.swapped.corners(t as usize).map(|v| v.as_dvec3().to_array());
                column_hit(&triangle, [q.x, q.y])
            })
            .map(|hit| (hit.z, -i32::from(hit.sign)))
            .collect()
    }
}

/// W″ at height `y` on a vertical line with these [`UpColumns::crossings`].
pub fn net_above(crossings: &[(f64, i32)], y: f64) -> i32 {
    crossings
        .iter()
        .filter(|(height, _)| *height > y)
        .map(|(_, sign)| sign)
        .sum()
}

/// A point's (x, z) footprint.
fn footprint(p: DVec3) -> DVec2 {
    DVec2::new(p.x, p.z)
}

/// The curtain under one boundary edge: the points straight below the edge.
#[derive(Clone, Copy, Debug)]
pub struct Wall {
    a: DVec3,
    b: DVec3,
}

/// The curtain's walls, one per boundary edge.
pub fn walls(mesh: &Mesh, boundary: &[BoundaryEdge]) -> Vec<Wall> {
    boundary
        .iter()
        .map(|e| Wall {
            a: mesh.positions[e.a as usize].as_dvec3(),
            b: mesh.positions[e.b as usize].as_dvec3(),
        })
        .collect()
}

/// Share of the walls' and triangles' size by which [`Wall::meets`] errs towards "meets".
const MEETS_SLACK: f64 = 1e-9;

impl Wall {
    /// Whether any of `triangles` meets the wall, or may: those whose bounds miss the wall's
    /// are passed over.
    pub fn meets_any(&self, triangles: &[[DVec3; 3]]) -> bool {
        let (lo, hi) = point_bounds(triangles.iter().flatten().copied());
        let slack = MEETS_SLACK * ((hi - lo).max_element() + (self.b - self.a).abs().max_element()) + 1e-12;
        let (wlo, whi) = (self.a.min(self.b), self.a.max(self.b));
        let misses = lo.x > whi.x + slack
            || hi.x < wlo.x - slack
            || lo.z > whi.z + slack
            || hi.z < wlo.z - slack
            || lo.y > whi.y + slack;
        !misses && triangles.iter().any(|t| self.meets(t))
    }

    /// Whether `triangle` meets the wall, or may: rounding only ever adds a "yes". A triangle
    /// that meets no wall, and crosses the surface nowhere, has one W″ over all its points.
    pub fn meets(&self, triangle: &[DVec3; 3]) -> bool {
        let run = footprint(self.b - self.a);
        let size = (self.b - self.a).abs().max_element()
            + triangle
                .iter()
                .map(|p| (*p - self.a).abs().max_element())
                .fold(0.0, f64::max);
        let slack = MEETS_SLACK * size.max(f64::MIN_POSITIVE);
        if run.length() <= slack {
            // An edge straight up and down: the wall is the line below its higher end.
            let top = self.a.y.max(self.b.y);
            return below_line_meets(triangle, footprint(self.a), top, slack);
        }
        // The wall's plane holds the edge and the vertical; across it, the horizontal normal.
        let normal = DVec2::new(-run.y, run.x) / run.length();
        let across = triangle.map(|p| footprint(p - self.a).dot(normal));
        if across.iter().all(|&d| d > slack) || across.iter().all(|&d| d < -slack) {
            return false;
        }
        // Where the triangle meets the plane, in the wall's coordinates: along the edge (0 to
        // 1) and height. A triangle lying in the plane counts as meeting it.
        let along = |p: DVec3| footprint(p - self.a).dot(run) / run.length_squared();
        let mut section = Vec::with_capacity(3);
        for i in 0..3 {
            let (p, q, dp, dq) = (triangle[i], triangle[(i + 1) % 3], across[i], across[(i + 1) % 3]);
            if dp.abs() <= slack {
                section.push(DVec2::new(along(p), p.y));
            }
            if (dp > slack && dq < -slack) || (dp < -slack && dq > slack) {
                let x = p + (q - p) * (dp / (dp - dq));
                section.push(DVec2::new(along(x), x.y));
            }
        }
        if section.is_empty() {
            return false;
        }
        if section.len() > 2 || across.iter().all(|d| d.abs() <= slack) {
            return true;
        }
        let (p, q) = (section[0], *section.last().expect("not empty"));
        segment_meets_wall(p, q, self.a.y, self.b.y, slack / run.length().max(slack))
    }
}

/// The cells of a panel's grid (nu × nv, v fastest; cell (i, j) spans the grid points `at(i, j)`
/// to `at(i + 1, j + 1)`) for which W″ may be 0 somewhere: each piece between walls where
/// W″ = 0, and, unless `near_answered`, the cells a wall meets. A piece meets no wall and,
/// like every panel, crosses the surface nowhere, so W″ is one value over it.
pub fn unanswered_cells(
    walls: &[Wall],
    up: &UpColumns,
    at: impl Fn(usize, usize) -> DVec3,
    [nu, nv]: [usize; 2],
    near_answered: bool,
) -> Vec<bool> {
    let cell = |i: usize, j: usize| {
        let [a, b, c, d] = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
        [[a, b, c], [a, c, d]]
    };
    let whole = [at(0, 0), at(nu, 0), at(nu, nv), at(0, nv)];
    let panel = [[whole[0], whole[1], whole[2]], [whole[0], whole[2], whole[3]]];
    let near: Vec<&Wall> = walls.iter().filter(|w| w.meets_any(&panel)).collect();
    let on_wall: Vec<bool> = (0..nu * nv)
        .map(|k| near.iter().any(|w| w.meets_any(&cell(k / nv, k % nv))))
        .collect();
    let mut open = if near_answered {
        vec![false; nu * nv]
    } else {
        on_wall.clone()
    };
    // Each piece: the cells a wall meets nowhere, joined across shared sides.
    let mut piece = on_wall;
    let mut stack = Vec::new();
    for start in 0..nu * nv {
        if piece[start] {
            continue;
        }
        let (mut members, centre) = (Vec::new(), cell(start / nv, start % nv));
        let centre = (centre[0][0] + centre[0][2]) / 2.0;
        piece[start] = true;
        stack.push(start);
        while let Some(k) = stack.pop() {
            members.push(k);
            let (i, j) = (k / nv, k % nv);
            let sides = [
                (i > 0).then(|| k - nv),
                (i + 1 < nu).then(|| k + nv),
                (j > 0).then(|| k - 1),
                (j + 1 < nv).then(|| k + 1),
            ];
            for n in sides.into_iter().flatten() {
                if !piece[n] {
                    piece[n] = true;
                    stack.push(n);
                }
            }
        }
        if up.net_crossings_above(centre) == 0 {
            for k in members {
                open[k] = true;
            }
        }
    }
    open
}

/// Whether the vertical line at `at` meets `triangle` at a height no more than `top`, give or
/// take `slack`.
fn below_line_meets(triangle: &[DVec3; 3], at: DVec2, top: f64, slack: f64) -> bool {
    let swapped = triangle.map(|v| swap(v).to_array());
    // Near the line, a few nudged lines stand in for the triangle's closed footprint.
    [DVec2::ZERO, DVec2::X, DVec2::NEG_X, DVec2::Y, DVec2::NEG_Y]
        .iter()
        .filter_map(|d| column_hit(&swapped, (at + *d * slack).to_array()))
        .any(|hit| hit.z <= top + slack)
        || triangle
            .iter()
            .map(|p| footprint(*p).distance(at))
            .fold(f64::INFINITY, f64::min)
            <= slack
            && triangle.iter().any(|p| p.y <= top + slack)
}

/// Whether the segment p–q of the wall's plane (along the edge, height) meets the wall: along
/// in [0, 1], no higher than the edge there (from height `ya` to `yb`). Liang–Barsky clipping,
/// each bound loosened by `slack`.
fn segment_meets_wall(p: DVec2, q: DVec2, ya: f64, yb: f64, slack: f64) -> bool {
    let d = q - p;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    // Each bound as value(t) = c + k·t ≤ 0.
    let bounds = [
        (-p.x - slack, -d.x),
        (p.x - 1.0 - slack, d.x),
        (
            p.y - (ya + p.x * (yb - ya)) - slack * (1.0 + ya.abs() + yb.abs()),
            d.y - d.x * (yb - ya),
        ),
    ];
    for (c, k) in bounds {
        if k == 0.0 {
            if c > 0.0 {
                return false;
            }
        } else if k > 0.0 {
            t1 = t1.min(-c / k);
        } else {
            t0 = t0.max(-c / k);
        }
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// The tiles (`tile` pixels a side, `tiles` a row, a row after another) of sky view `view` that
/// lie within `margin` pixels of a wall's image: the band, grown.
pub fn window(view: &View, walls: &[Wall], margin: f64, tile: usize) -> Vec<bool> {
    let tiles = view.pixels / tile;
    let mut inside = vec![false; tiles * tiles];
    // A wall's image: its edge's image swept along the image of straight down, far enough to
    // leave the frame.
    let down = (view.project(DVec3::NEG_Y) - view.project(DVec3::ZERO)).truncate();
    let far = if down.length() > 0.0 {
        down * (4.0 * view.pixels as f64 / down.length())
    } else {
        DVec2::ZERO
    };
    for wall in walls {
        let (a, b) = (view.project(wall.a).truncate(), view.project(wall.b).truncate());
        let corners = [a, b, b + far, a + far];
        let (lo, hi) = corners
            .iter()
            .fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(lo, hi), c| {
                (lo.min(*c), hi.max(*c))
            });
        let (lo, hi) = ((lo - margin) / tile as f64, (hi + margin) / tile as f64);
        if hi.x < 0.0 || hi.y < 0.0 || lo.x >= tiles as f64 || lo.y >= tiles as f64 {
            continue;
        }
        let index = |v: f64| clamped_index(v, tiles);
        for ty in index(lo.y)..=index(hi.y) {
            for tx in index(lo.x)..=index(hi.x) {
                let k = ty * tiles + tx;
                if !inside[k] {
                    let square = [
                        DVec2::new((tx * tile) as f64, (ty * tile) as f64) - margin,
                        DVec2::new(((tx + 1) * tile) as f64, ((ty + 1) * tile) as f64) + margin,
                    ];
                    inside[k] = square_meets_quad(square, &corners);
                }
            }
        }
    }
    inside
}

/// Whether the square [lo, hi] meets the convex quadrilateral `quad` (which may be flat): no
/// axis of either separates them.
fn square_meets_quad([lo, hi]: [DVec2; 2], quad: &[DVec2; 4]) -> bool {
    let square = [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)];
    let separates = |axis: DVec2| {
        let span = |points: &[DVec2]| {
            points
                .iter()
                .map(|p| p.dot(axis))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)))
        };
        let ((a0, a1), (b0, b1)) = (span(&square), span(quad));
        a1 < b0 || b1 < a0
    };
    let edges = (0..4)
        .map(|i| quad[(i + 1) % 4] - quad[i])
        .filter(|e| e.length_squared() > 0.0);
    ![DVec2::X, DVec2::Y]
        .into_iter()
        .chain(edges.map(|e| e.perp()))
        .any(separates)
}

#[cfg(test)]
mod tests {
    use super::super::tests::open_cube;
    use super::*;

    /// The top face of [`crate::occluder::BOX_FACES`] (y = 1).
    const TOP: usize = 3;

    #[test]
    fn net_crossings_above_count_the_surface_over_a_point() {
        let (closed, _) = open_cube(None);
        let columns = UpColumns::new(&closed);
        // Inside, one crossing above (the top, facing up); above and beside it, none.
        assert_eq!(columns.net_crossings_above(DVec3::new(0.3, 0.5, 0.6)), 1);
        assert_eq!(columns.net_crossings_above(DVec3::new(0.3, 1.5, 0.6)), 0);
        assert_eq!(columns.net_crossings_above(DVec3::new(0.3, -0.5, 0.6)), 0);
        assert_eq!(columns.net_crossings_above(DVec3::new(1.3, 0.5, 0.6)), 0);
        // Through an edge of the top's two triangles, still one.
        assert_eq!(columns.net_crossings_above(DVec3::new(0.5, 0.5, 0.5)), 1);
        // Open at the top: nothing above the inside.
        let (open, _) = open_cube(Some(TOP));
        let columns = UpColumns::new(&open);
        assert_eq!(columns.net_crossings_above(DVec3::new(0.3, 0.5, 0.6)), 0);
        // Below the bottom, the bottom (facing down) and nothing else.
        assert_eq!(columns.net_crossings_above(DVec3::new(0.3, -0.5, 0.6)), -1);
    }

    #[test]
    fn a_triangle_meets_the_wall_where_it_reaches_below_the_edge() {
        let wall = Wall {
            a: DVec3::new(0.0, 1.0, 0.0),
            b: DVec3::new(1.0, 2.0, 0.0),
        };
        let across = |y: f64, x: f64| {
            [
                DVec3::new(x, y, -1.0),
                DVec3::new(x, y, 1.0),
                DVec3::new(x + 0.1, y - 0.1, 1.0),
            ]
        };
        // Across the wall's plane, below the edge (which is at 1.5 at x = 0.5), above it, and
        // past its end.
        assert!(wall.meets(&across(1.4, 0.5)));
        assert!(wall.meets(&across(-10.0, 0.5)));
        assert!(!wall.meets(&across(1.7, 0.5)));
        assert!(!wall.meets(&across(0.0, 1.5)));
        // Wholly to one side of the plane.
        let beside = [
            DVec3::new(0.5, 0.0, 0.5),
            DVec3::new(0.6, 0.0, 1.0),
            DVec3::new(0.5, 0.5, 1.0),
        ];
        assert!(!wall.meets(&beside));
        // A wall under an edge straight up and down is the line below its top.
        let line = Wall {
            a: DVec3::new(0.5, 0.0, 0.5),
            b: DVec3::new(0.5, 1.0, 0.5),
        };
        let flat = |y: f64| {
            [
                DVec3::new(0.0, y, 0.0),
                DVec3::new(1.0, y, 0.0),
                DVec3::new(0.0, y, 1.0),
            ]
        };
        assert!(line.meets(&flat(0.5)));
        assert!(!line.meets(&flat(1.5)));
    }

    #[test]
    fn the_window_holds_the_image_of_every_point_of_the_curtain() {
        let (open, boundary) = open_cube(Some(TOP));
        assert_eq!(boundary.len(), 4);
        let walls = walls(&open, &boundary);
        let (center, radius) = open.bounding_sphere();
        for dir in crate::geom::camera::fibonacci_sphere(64)
            .into_iter()
            .filter(|d| d.y >= 0.0)
        {
            let view = View::new(dir, center, radius, 256);
            let inside = window(&view, &walls, 2.0, 8);
            let hit = |p: DVec3| {
                let q = view.project(p);
                let (x, y) = (q.x as usize / 8, q.y as usize / 8);
                q.x < 0.0 || q.y < 0.0 || x >= 32 || y >= 32 || inside[y * 32 + x]
            };
            for wall in &walls {
                for s in 0..=10 {
                    let top = wall.a + (wall.b - wall.a) * (s as f64 / 10.0);
                    for depth in [0.0, 0.3, 1.0, 5.0] {
                        assert!(hit(top - DVec3::Y * depth), "{dir} {top} {depth}");
                    }
                }
            }
            assert!(inside.iter().any(|&t| !t), "{dir}: the band fills the view");
        }
    }

    #[test]
    fn a_panel_through_an_opening_is_unanswered_beyond_the_curtain() {
        // Open on the side at x = 1, where the curtain hangs from the top edge: inside, the
        // top lies over the panel (W″ = 1); outside, nothing does (W″ = 0).
        let (mesh, boundary) = open_cube(Some(1));
        let (walls, up) = (walls(&mesh, &boundary), UpColumns::new(&mesh));
        // Eight cells along x from 0.6 to 1.4: cells 3 and 4 touch the wall at x = 1.
        let at = |i: usize, j: usize| DVec3::new(0.6 + 0.1 * i as f64, 0.5, 0.2 + 0.1 * j as f64);
        let unanswered_columns = |near_answered: bool| {
            let cells = unanswered_cells(&walls, &up, at, [8, 6], near_answered);
            (0..8)
                .map(|i| cells[i * 6..(i + 1) * 6].iter().all(|&u| u))
                .collect::<Vec<_>>()
        };
        let beyond = |first: usize| (0..8).map(|i| i >= first).collect::<Vec<_>>();
        assert_eq!(unanswered_columns(true), beyond(5));
        assert_eq!(unanswered_columns(false), beyond(3));
        // A column of cells holds one answer.
        let cells = unanswered_cells(&walls, &up, at, [8, 6], true);
        assert!((0..8).all(|i| cells[i * 6..(i + 1) * 6].iter().all(|&u| u == cells[i * 6])));
    }
}
