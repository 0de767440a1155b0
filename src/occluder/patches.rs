//! On-surface patches: rectangles on flat parts of surfaces with no volume (roads, single-sided
//! walls, polygon soups). A patch lies on the surface, so it hides exactly what that surface
//! hides.
//!
//! Triangles are grouped by plane. In each group's plane, a 2D grid cell is covered when no edge
//! of the group's outline meets it and its centre lies in a triangle: then the whole cell lies in
//! the union of the group. Patches are the largest rectangles of covered cells.

use super::rectangle;
use super::{Panel, Shape};
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::collections::HashMap;

/// Most cells along a group's side; larger groups get coarser cells.
const MAX_CELLS: usize = 512;
/// Narrowest patch, in cells.
const MIN_SIDE: usize = 2;
/// Most patches per plane, and in all.
const MAX_PER_GROUP: usize = 16;
const MAX_PATCHES: usize = 256;
/// Triangles share a plane when their unit normals and offsets agree this closely (offsets
/// relative to the mesh's size).
const NORMAL_TOLERANCE: f64 = 1e-4;
const OFFSET_TOLERANCE: f64 = 1e-6;

/// Patches on the triangles marked in `candidates`, each at least `min_area`, on 2D cells of
/// side `cell` (or coarser for very large planes). Largest first.
pub fn find(mesh: &Mesh, candidates: &[bool], cell: f64, min_area: f64) -> Vec<Panel> {
    let (lo, hi) = mesh.bounds();
    let size = (hi - lo).as_dvec3().max_element();
    if size <= 0.0 || cell <= 0.0 {
        return Vec::new();
    }
    // Each triangle with its plane's key, sorted: a plane's triangles follow each other, in order.
    let mut keyed: Vec<([i64; 4], usize)> = (0..mesh.triangles.len())
        .into_par_iter()
        .filter(|&t| candidates[t])
        .filter_map(|t| {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let n = (b - a).cross(c - a).try_normalize()?;
            // Both sides of a plane are one group.
            let (n, _) = facing_up(n);
            let q = |x: f64, step: f64| (x / step).round() as i64;
            let key = [
                q(n.x, NORMAL_TOLERANCE),
                q(n.y, NORMAL_TOLERANCE),
                q(n.z, NORMAL_TOLERANCE),
                q(n.dot(a), OFFSET_TOLERANCE * size),
            ];
            Some((key, t))
        })
        .collect();
    keyed.par_sort_unstable();
    let mut groups: Vec<Vec<usize>> = keyed
        .chunk_by(|a, b| a.0 == b.0)
        .map(|plane| plane.iter().map(|&(_, t)| t).collect())
        .collect();
    // By first triangle (no two groups share one): the planes in the mesh's order.
    groups.sort_unstable();
    let mut patches: Vec<Panel> = groups
        .par_iter()
        .filter(|g| g.iter().map(|&t| area(mesh, t)).sum::<f64>() >= min_area)
        .flat_map_iter(|g| patches_on_plane(mesh, g, cell, min_area))
        .collect();
    patches.sort_by(|a, b| b.area().total_cmp(&a.area()));
    patches.truncate(MAX_PATCHES);
    patches
}

fn area(mesh: &Mesh, t: usize) -> f64 {
    let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
    0.5 * (b - a).cross(c - a).length()
}

fn patches_on_plane(mesh: &Mesh, group: &[usize], cell: f64, min_area: f64) -> Vec<Panel> {
    let frame = PlaneFrame::of(mesh, group);
    let flat = |v: u32| frame.flat(mesh.positions[v as usize].as_dvec3());
    let grid = PlaneGrid::around(group.iter().flat_map(|&t| mesh.triangles[t]).map(flat), cell);
    let mut covered = covered_cells(mesh, group, &flat, &grid);
    let mut patches = Vec::new();
    while patches.len() < MAX_PER_GROUP {
        let Some(r) = rectangle::largest(&covered, grid.dims[0], grid.dims[1], MIN_SIDE) else {
            break;
        };
        if r.cells() as f64 * grid.cell * grid.cell < min_area {
            break;
        }
        for (x, y) in r.iter() {
            covered[x * grid.dims[1] + y] = false;
        }
        let at = |x: usize, y: usize| frame.lift(grid.lo + DVec2::new(x as f64, y as f64) * grid.cell);
        patches.push(Panel {
            shape: Shape::Patches,
            corners: [
                at(r.u[0], r.v[0]),
                at(r.u[1], r.v[0]),
                at(r.u[1], r.v[1]),
                at(r.u[0], r.v[1]),
            ],
        });
    }
    patches
}

/// A normal turned so that its largest component is positive (both sides of a plane are one),
/// and the axis of that component.
fn facing_up(n: DVec3) -> (DVec3, usize) {
    let largest = (0..3)
        .max_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs()))
        .expect("three axes");
    (if n[largest] < 0.0 { -n } else { n }, largest)
}

/// A group's plane: its normal, two axes in it, and its mean offset along the normal.
struct PlaneFrame {
    normal: DVec3,
    e1: DVec3,
    e2: DVec3,
    offset: f64,
}

impl PlaneFrame {
    fn of(mesh: &Mesh, group: &[usize]) -> PlaneFrame {
        let [a, b, c] = mesh.corners(group[0]).map(|p| p.as_dvec3());
        let (normal, largest) = facing_up((b - a).cross(c - a).normalize());
        // Axis-aligned planes get axis-aligned rectangles; others follow their longest edge.
        let e1 = if normal[largest] > 1.0 - 1e-9 {
            let mut e = DVec3::ZERO;
            e[(largest + 1) % 3] = 1.0;
            e
        } else {
            let (p, q) = group
                .iter()
                .flat_map(|&t| {
                    let v = mesh.corners(t).map(|p| p.as_dvec3());
                    [(v[0], v[1]), (v[1], v[2]), (v[2], v[0])]
                })
                .max_by(|x, y| (x.1 - x.0).length_squared().total_cmp(&(y.1 - y.0).length_squared()))
                .expect("a group has triangles");
            let d = q - p;
            (d - normal * d.dot(normal)).normalize()
        };
        let offset = group
            .iter()
            .flat_map(|&t| mesh.triangles[t])
            .map(|v| normal.dot(mesh.positions[v as usize].as_dvec3()))
            .sum::<f64>()
            / (3 * group.len()) as f64;
        PlaneFrame {
            normal,
            e1,
            e2: normal.cross(e1),
            offset,
        }
    }

    /// A point's coordinates in the plane.
    fn flat(&self, p: DVec3) -> DVec2 {
        DVec2::new(p.dot(self.e1), p.dot(self.e2))
    }

    /// The point of the plane at `p`.
    fn lift(&self, p: DVec2) -> [f64; 3] {
        (self.e1 * p.x + self.e2 * p.y + self.normal * self.offset).to_array()
    }
}

/// Square cells of side `cell` over a plane's points, from `lo`.
struct PlaneGrid {
    lo: DVec2,
    cell: f64,
    dims: [usize; 2],
}

impl PlaneGrid {
    /// Cells of side `cell` (or coarser, for at most MAX_CELLS a side) over `points`.
    fn around(points: impl Iterator<Item = DVec2>, cell: f64) -> PlaneGrid {
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in points {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let cell = cell.max((hi - lo).max_element() / MAX_CELLS as f64);
        let dims = [
            (((hi.x - lo.x) / cell).ceil() as usize).max(1),
            (((hi.y - lo.y) / cell).ceil() as usize).max(1),
        ];
        PlaneGrid { lo, cell, dims }
    }

    /// The cells along axis `k` that [a, b] may reach.
    fn cell_range(&self, k: usize, a: f64, b: f64) -> std::ops::Range<usize> {
        let from = ((a - self.lo[k]) / self.cell - 1.0).ceil().max(0.0) as usize;
        let to = (((b - self.lo[k]) / self.cell).floor() as i64 + 1).clamp(0, self.dims[k] as i64) as usize;
        from.min(to)..to
    }
}

/// The cells the group's triangles cover whole: those whose centre a triangle covers, less
/// those the group's outline passes through.
fn covered_cells(mesh: &Mesh, group: &[usize], flat: &impl Fn(u32) -> DVec2, grid: &PlaneGrid) -> Vec<bool> {
    let (lo, cell, dims) = (grid.lo, grid.cell, grid.dims);
    let mut covered = vec![false; dims[0] * dims[1]];
    // Edges counted with the side their triangle lies on: the outline is where they do not cancel.
    let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
    for &t in group {
        let tri = mesh.triangles[t];
        let q = tri.map(flat);
        let area = cross(q[1] - q[0], q[2] - q[0]);
        if area == 0.0 {
            continue;
        }
        let tlo = q[0].min(q[1]).min(q[2]);
        let thi = q[0].max(q[1]).max(q[2]);
        for x in grid.cell_range(0, tlo.x, thi.x) {
            for y in grid.cell_range(1, tlo.y, thi.y) {
                let p = lo + DVec2::new(x as f64 + 0.5, y as f64 + 0.5) * cell;
                let inside = (0..3).all(|k| cross(q[(k + 1) % 3] - q[k], p - q[k]) * area >= 0.0);
                covered[x * dims[1] + y] |= inside;
            }
        }
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let side = if (a < b) == (area > 0.0) { 1 } else { -1 };
            *edges.entry((a.min(b), a.max(b))).or_default() += side;
        }
    }
    // Cells that the outline passes through are not wholly covered.
    for (&(a, b), _) in edges.iter().filter(|(_, net)| **net != 0) {
        let (p, q) = (flat(a), flat(b));
        for x in grid.cell_range(0, p.x.min(q.x), p.x.max(q.x)) {
            for y in grid.cell_range(1, p.y.min(q.y), p.y.max(q.y)) {
                let c0 = lo + DVec2::new(x as f64, y as f64) * cell;
                if segment_meets_box(p, q, c0, c0 + cell) {
                    covered[x * dims[1] + y] = false;
                }
            }
        }
    }
    covered
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether segment p–q meets the closed box [lo, hi] (Liang–Barsky clipping).
fn segment_meets_box(p: DVec2, q: DVec2, lo: DVec2, hi: DVec2) -> bool {
    let d = q - p;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..2 {
        if d[k] == 0.0 {
            if p[k] < lo[k] || p[k] > hi[k] {
                return false;
            }
            continue;
        }
        let (mut a, mut b) = ((lo[k] - p[k]) / d[k], (hi[k] - p[k]) / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        t0 = t0.max(a);
        t1 = t1.min(b);
        if t0 > t1 {
            return false;
        }
    }
    true
}
