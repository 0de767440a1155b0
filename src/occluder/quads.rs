//! In-solid quads, after Voxel Farm's occluder quads: rectangles on planes that lie inside the
//! solid over their whole area. They cover walls far thinner than a voxel, because the search
//! runs on a 2D grid per axis that can be much finer than the 3D one.
//!
//! For each axis of a frame, each cell of a 2D grid over the other two axes is a prism along the
//! axis. Every triangle that meets the prism, clipped to it, blocks the range of heights it spans
//! there. Between two blocked ranges the prism's cross-section meets no surface, so it is inside
//! or outside as a whole, and one point query decides which. A plane is open in a cell when it
//! lies in such an inside gap; a quad is a rectangle of cells in which one plane is open. The
//! test holds for the cell's whole footprint, not only at a sample, so the quad is inside
//! everywhere.
//!
//! Besides the world axes, frames turned by 45° about each axis give diagonal quads, which cover
//! what oblique views see of rounded shapes.

use super::rectangle::{self, CellRect};
use super::{Panel, Shape};
use crate::mesh::{Mesh, point_bounds};
use glam::{DQuat, DVec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::f64::consts::FRAC_PI_4;

/// Most quads kept per axis of a frame.
const MAX_PER_AXIS: usize = 24;
/// Smallest quad, in grid cells, and its narrowest side: a strip one cell wide covers next to
/// nothing.
const MIN_CELLS: usize = 16;
const MIN_SIDE: usize = 2;
/// Most planes tried per axis besides the evenly spaced ones.
const MAX_GAP_PLANES: usize = 64;
/// Cells between the evenly spaced planes.
const PLANE_SPACING: f64 = 4.0;

/// A range of heights along the axis where the cell's cross-section is inside the solid.
#[derive(Clone, Copy, Debug)]
struct Gap {
    lo: f64,
    hi: f64,
    used: bool,
}

/// The 2D grid of one axis of a frame: cells of size `cell` from `origin` over the frame's axes
/// `(axis+1, axis+2) % 3`. The frame's coordinates of a world point p are `turn * p`.
struct AxisGrid {
    turn: DQuat,
    axis: usize,
    origin: [f64; 2],
    cell: f64,
    dims: [usize; 2],
}

impl AxisGrid {
    /// A world point in grid coordinates (u, v, height).
    fn uv(&self, p: DVec3) -> [f64; 3] {
        let p = self.turn * p;
        [p[(self.axis + 1) % 3], p[(self.axis + 2) % 3], p[self.axis]]
    }

    /// The world point at grid coordinates (u, v, height).
    fn point(&self, u: f64, v: f64, t: f64) -> DVec3 {
        let mut p = DVec3::ZERO;
        p[(self.axis + 1) % 3] = u;
        p[(self.axis + 2) % 3] = v;
        p[self.axis] = t;
        self.turn.inverse() * p
    }

    /// Cells whose closed footprint meets [lo, hi] along grid axis k.
    fn range(&self, k: usize, lo: f64, hi: f64) -> std::ops::Range<usize> {
        let a = ((lo - self.origin[k]) / self.cell - 1.0).ceil().max(0.0) as usize;
        let b = (((hi - self.origin[k]) / self.cell).floor() as i64 + 1).clamp(0, self.dims[k] as i64) as usize;
        a.min(b)..b
    }
}

/// Quads inside the solid, up to `MAX_PER_AXIS` per axis and frame. `grid` is the number of
/// cells along the mesh's longest side; `inside` is the solid classification at a world point.
pub fn find(mesh: &Mesh, grid: usize, inside: &(dyn Fn(DVec3) -> bool + Sync)) -> Vec<Panel> {
    let frames = [
        DQuat::IDENTITY,
        DQuat::from_rotation_x(FRAC_PI_4),
        DQuat::from_rotation_y(FRAC_PI_4),
        DQuat::from_rotation_z(FRAC_PI_4),
    ];
    let passes: Vec<(DQuat, usize)> = frames.iter().flat_map(|&f| (0..3).map(move |axis| (f, axis))).collect();
    passes
        .par_iter()
        .flat_map_iter(|&(turn, axis)| {
            let (lo, hi) = point_bounds(mesh.positions.iter().map(|p| turn * p.as_dvec3()));
            let size = (hi - lo).max_element();
            let cell = size / grid as f64;
            if cell <= 0.0 || !cell.is_finite() {
                return Vec::new();
            }
            let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
            let g = AxisGrid {
                turn,
                axis,
                origin: [lo[ua], lo[va]],
                cell,
                dims: [
                    (((hi[ua] - lo[ua]) / cell).ceil() as usize).max(1),
                    (((hi[va] - lo[va]) / cell).ceil() as usize).max(1),
                ],
            };
            // Keeps quads clear of the surface by more than rounding to f32 can move them.
            let margin = 1e-6 * size;
            let gaps = inside_gaps(mesh, &g, margin, inside);
            let planes = candidate_planes(&gaps, lo[axis], hi[axis], cell);
            best_rectangles(&g, gaps, &planes, margin)
        })
        .collect()
}

/// For every cell, the gaps between blocked height ranges whose cross-section is inside.
fn inside_gaps(mesh: &Mesh, g: &AxisGrid, margin: f64, inside: &(dyn Fn(DVec3) -> bool + Sync)) -> Vec<Vec<Gap>> {
    let nv = g.dims[1];
    let cells = g.dims[0] * nv;
    let blocked: Vec<(u32, f64, f64)> = (0..mesh.triangles.len())
        .into_par_iter()
        .fold(Vec::new, |mut out, t| {
            let tri = mesh.corners(t).map(|p| g.uv(p.as_dvec3()));
            let lo = |k: usize| tri.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
            let hi = |k: usize| tri.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
            let (ru, rv) = (g.range(0, lo(0), hi(0)), g.range(1, lo(1), hi(1)));
            if ru.len() == 1 && rv.len() == 1 {
                // Wholly inside one cell: no clipping.
                out.push(((ru.start * nv + rv.start) as u32, lo(2), hi(2)));
                return out;
            }
            for u in ru {
                for v in rv.clone() {
                    let u0 = g.origin[0] + u as f64 * g.cell;
                    let v0 = g.origin[1] + v as f64 * g.cell;
                    if let Some((t0, t1)) = clipped_heights(&tri, [u0, u0 + g.cell], [v0, v0 + g.cell]) {
                        out.push(((u * nv + v) as u32, t0, t1));
                    }
                }
            }
            out
        })
        .reduce(Vec::new, |mut a, mut b| {
            a.append(&mut b);
            a
        });
    // Counting sort by cell.
    let mut starts = vec![0usize; cells + 1];
    for &(c, _, _) in &blocked {
        starts[c as usize + 1] += 1;
    }
    for c in 0..cells {
        starts[c + 1] += starts[c];
    }
    let mut ranges = vec![(0.0f64, 0.0f64); blocked.len()];
    let mut next = starts.clone();
    for &(c, t0, t1) in &blocked {
        ranges[next[c as usize]] = (t0, t1);
        next[c as usize] += 1;
    }
    let mut by_cell: Vec<&mut [(f64, f64)]> = Vec::with_capacity(cells);
    let mut rest = ranges.as_mut_slice();
    for c in 0..cells {
        let (head, tail) = rest.split_at_mut(starts[c + 1] - starts[c]);
        by_cell.push(head);
        rest = tail;
    }
    by_cell
        .into_par_iter()
        .enumerate()
        .map(|(c, ranges)| {
            ranges.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let (u, v) = (c / nv, c % nv);
            let center = [
                g.origin[0] + (u as f64 + 0.5) * g.cell,
                g.origin[1] + (v as f64 + 0.5) * g.cell,
            ];
            let mut gaps = Vec::new();
            let mut top = f64::NEG_INFINITY;
            for &(t0, t1) in ranges.iter() {
                if top > f64::NEG_INFINITY && t0 - top > 2.0 * margin {
                    let mid = 0.5 * (top + t0);
                    if inside(g.point(center[0], center[1], mid)) {
                        gaps.push(Gap {
                            lo: top,
                            hi: t0,
                            used: false,
                        });
                    }
                }
                top = top.max(t1);
            }
            gaps
        })
        .collect()
}

/// The heights that triangle `tri` (in (u, v, t)) spans over the closed rectangle
/// [u0, u1] × [v0, v1], if it meets it: Sutherland–Hodgman clipping.
fn clipped_heights(tri: &[[f64; 3]; 3], u: [f64; 2], v: [f64; 2]) -> Option<(f64, f64)> {
    // A triangle clipped by four lines has at most seven corners.
    let mut poly = [[0.0f64; 3]; 8];
    poly[..3].copy_from_slice(tri);
    let mut len = 3;
    // (coordinate, bound, keep the side where coordinate >= bound)
    for (k, bound, above) in [(0, u[0], true), (0, u[1], false), (1, v[0], true), (1, v[1], false)] {
        let keeps = |p: &[f64; 3]| if above { p[k] >= bound } else { p[k] <= bound };
        if poly[..len].iter().all(keeps) {
            continue;
        }
        let mut next = [[0.0f64; 3]; 8];
        let mut next_len = 0;
        for i in 0..len {
            let (a, b) = (poly[i], poly[(i + 1) % len]);
            if keeps(&a) {
                next[next_len] = a;
                next_len += 1;
            }
            if keeps(&a) != keeps(&b) {
                let s = (bound - a[k]) / (b[k] - a[k]);
                next[next_len] = std::array::from_fn(|j| if j == k { bound } else { a[j] + s * (b[j] - a[j]) });
                next_len += 1;
            }
        }
        (poly, len) = (next, next_len);
        if len == 0 {
            return None;
        }
    }
    let heights = poly[..len].iter().map(|p| p[2]);
    let t0 = heights.clone().fold(f64::INFINITY, f64::min);
    let t1 = heights.fold(f64::NEG_INFINITY, f64::max);
    Some((t0, t1))
}

/// Planes worth trying: evenly spaced along the axis, plus the middles of the thin gaps
/// (walls thinner than a cell) that many cells share.
fn candidate_planes(gaps: &[Vec<Gap>], lo: f64, hi: f64, cell: f64) -> Vec<f64> {
    let step = PLANE_SPACING * cell;
    let steps = ((hi - lo) / step).ceil().max(1.0) as usize;
    let mut planes: Vec<f64> = (0..steps).map(|k| lo + (k as f64 + 0.5) * step).collect();
    let quantum = cell / 64.0;
    let mut thin: HashMap<i64, (usize, f64)> = HashMap::new();
    for gap in gaps.iter().flatten().filter(|g| g.hi - g.lo < 2.0 * cell) {
        let mid = 0.5 * (gap.lo + gap.hi);
        let entry = thin.entry((mid / quantum).round() as i64).or_insert((0, mid));
        entry.0 += 1;
    }
    let mut thin: Vec<(usize, f64)> = thin.into_values().collect();
    thin.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.total_cmp(&b.1)));
    planes.extend(thin.iter().take(MAX_GAP_PLANES).map(|&(_, mid)| mid));
    planes
}

/// The gap of a cell that holds plane `t` with `margin` to spare.
fn gap_at(gaps: &[Gap], t: f64, margin: f64) -> Option<usize> {
    gaps.iter().position(|g| g.lo + margin < t && t < g.hi - margin)
}

/// Where one candidate plane is open: the cells with the gap that holds the plane, and the
/// largest rectangle of those whose gap is still unused.
struct PlaneCells {
    t: f64,
    cells: Vec<(usize, usize)>,
    best: Option<CellRect>,
    /// The cells of `best`; while `stale`, only an upper bound on them.
    bound: usize,
    /// Not searched since the open cells last changed under `best`: at first, and after a
    /// taken rectangle overlaps it.
    stale: bool,
}

impl PlaneCells {
    fn new(gaps: &[Vec<Gap>], t: f64, margin: f64) -> PlaneCells {
        let cells: Vec<(usize, usize)> = gaps
            .iter()
            .enumerate()
            .filter_map(|(c, g)| gap_at(g, t, margin).map(|k| (c, k)))
            .collect();
        // No rectangle has more cells than the plane has open.
        PlaneCells {
            t,
            bound: cells.len(),
            cells,
            best: None,
            stale: true,
        }
    }

    /// Recomputes `best` over the cells whose gap is unused. Used gaps stay used, so they leave
    /// the list for good, and the search grid shrinks to what is left.
    fn update(&mut self, gaps: &[Vec<Gap>], nv: usize) {
        self.cells.retain(|&(c, k)| !gaps[c][k].used);
        self.best = None;
        self.bound = 0;
        self.stale = false;
        if self.cells.is_empty() {
            return;
        }
        let mut bounds = CellRect {
            u: [usize::MAX, 0],
            v: [usize::MAX, 0],
        };
        for &(c, _) in &self.cells {
            let (u, v) = (c / nv, c % nv);
            bounds.u = [bounds.u[0].min(u), bounds.u[1].max(u + 1)];
            bounds.v = [bounds.v[0].min(v), bounds.v[1].max(v + 1)];
        }
        let (bu, bv) = (bounds.u[1] - bounds.u[0], bounds.v[1] - bounds.v[0]);
        let mut mask = vec![false; bu * bv];
        for &(c, _) in &self.cells {
            mask[(c / nv - bounds.u[0]) * bv + c % nv - bounds.v[0]] = true;
        }
        self.best = rectangle::largest(&mask, bu, bv, MIN_SIDE)
            .filter(|r| r.cells() >= MIN_CELLS)
            .map(|r| CellRect {
                u: r.u.map(|u| u + bounds.u[0]),
                v: r.v.map(|v| v + bounds.v[0]),
            });
        self.bound = self.best.map_or(0, |r| r.cells());
    }
}

/// Greedy: the largest open rectangle over all candidate planes, then the next on what is left.
/// A plane is searched only once an upper bound on its rectangle leads all others: its open
/// cells at first; after a taken rectangle meets its best, that best. These are lazy greedy
/// picks, the same as searching every plane at first and again whenever it loses cells.
fn best_rectangles(g: &AxisGrid, mut gaps: Vec<Vec<Gap>>, planes: &[f64], margin: f64) -> Vec<Panel> {
    let nv = g.dims[1];
    let mut candidates: Vec<PlaneCells> = planes.par_iter().map(|&t| PlaneCells::new(&gaps, t, margin)).collect();
    let mut quads = Vec::new();
    while quads.len() < MAX_PER_AXIS {
        let Some(top) = (0..candidates.len())
            .filter(|&i| candidates[i].bound > 0)
            .max_by(|&a, &b| {
                let (a, b) = (&candidates[a], &candidates[b]);
                a.bound.cmp(&b.bound).then(b.t.total_cmp(&a.t))
            })
        else {
            break;
        };
        let candidate = &mut candidates[top];
        if candidate.stale {
            candidate.update(&gaps, nv);
            continue;
        }
        let (rect, plane) = (candidate.best.expect("a fresh bound counts its best"), candidate.t);
        // Centre the quad in the heights that every cell of the rectangle leaves open.
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for (u, v) in rect.iter() {
            let c = u * nv + v;
            let k = gap_at(&gaps[c], plane, margin).expect("the rectangle's cells hold the plane");
            lo = lo.max(gaps[c][k].lo);
            hi = hi.min(gaps[c][k].hi);
            gaps[c][k].used = true;
        }
        let overlaps =
            |r: &CellRect| r.u[0] < rect.u[1] && rect.u[0] < r.u[1] && r.v[0] < rect.v[1] && rect.v[0] < r.v[1];
        for p in candidates.iter_mut().filter(|p| p.best.as_ref().is_some_and(overlaps)) {
            p.stale = true;
        }
        let t = 0.5 * (lo + hi);
        let u = rect.u.map(|k| g.origin[0] + k as f64 * g.cell);
        let v = rect.v.map(|k| g.origin[1] + k as f64 * g.cell);
        let corners = [(u[0], v[0]), (u[1], v[0]), (u[1], v[1]), (u[0], v[1])];
        quads.push(Panel {
            shape: Shape::Quads,
            corners: corners.map(|(a, b)| g.point(a, b, t).to_array()),
        });
    }
    quads
}
