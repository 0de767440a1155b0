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

use super::rectangle::{CellRect, Sweep};
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
}

impl Gap {
    /// Whether a plane at height `t` lies in it with `margin` to spare ([`Planes::holding`]
    /// finds the planes this holds, in order of height).
    fn holds(&self, t: f64, margin: f64) -> bool {
        self.lo + margin < t && t < self.hi - margin
    }
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
            best_rectangles(&g, &gaps, &planes, margin)
        })
        .collect()
}

/// For every cell, the gaps between blocked height ranges whose cross-section is inside.
fn inside_gaps(mesh: &Mesh, g: &AxisGrid, margin: f64, inside: &(dyn Fn(DVec3) -> bool + Sync)) -> Vec<Vec<Gap>> {
    let nv = g.dims[1];
    let cells = g.dims[0] * nv;
    let blocked: Vec<(u32, (f64, f64))> = (0..mesh.triangles.len())
        .into_par_iter()
        .fold(Vec::new, |mut out, t| {
            let tri = mesh.corners(t).map(|p| g.uv(p.as_dvec3()));
            let lo = |k: usize| tri.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
            let hi = |k: usize| tri.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
            let (ru, rv) = (g.range(0, lo(0), hi(0)), g.range(1, lo(1), hi(1)));
            if ru.len() == 1 && rv.len() == 1 {
                // Wholly inside one cell: no clipping.
                out.push(((ru.start * nv + rv.start) as u32, (lo(2), hi(2))));
                return out;
            }
            // A cell wholly inside the triangle's footprint takes its heights from the plane;
            // only one wider than a cell each way can hold one.
            let footprint = (hi(0) - lo(0) > g.cell && hi(1) - lo(1) > g.cell)
                .then(|| Footprint::new(&tri))
                .flatten();
            // Clip to each column's strip once, then the strip to each cell of it.
            for u in ru {
                let u0 = g.origin[0] + u as f64 * g.cell;
                let Some(strip) = Polygon::triangle(&tri).clip(0, [u0, u0 + g.cell]) else {
                    continue;
                };
                for v in rv.clone() {
                    let v0 = g.origin[1] + v as f64 * g.cell;
                    let cell = [[u0, u0 + g.cell], [v0, v0 + g.cell]];
                    let heights = footprint.as_ref().and_then(|f| f.heights_over(cell));
                    if let Some(heights) = heights.or_else(|| strip.heights_within(1, cell[1])) {
                        out.push(((u * nv + v) as u32, heights));
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
    for &(c, _) in &blocked {
        starts[c as usize + 1] += 1;
    }
    for c in 0..cells {
        starts[c + 1] += starts[c];
    }
    let mut ranges = vec![(0.0f64, 0.0f64); blocked.len()];
    let mut next = starts.clone();
    for &(c, heights) in &blocked {
        ranges[next[c as usize]] = heights;
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
                        gaps.push(Gap { lo: top, hi: t0 });
                    }
                }
                top = top.max(t1);
            }
            gaps
        })
        .collect()
}

/// A triangle in (u, v, t) seen along t: its edges' functions and its plane.
struct Footprint {
    /// Per edge, (a, b, c) with a·u + b·v + c ≥ 0 on the triangle's side.
    edges: [[f64; 3]; 3],
    /// t = plane[2] + plane[3]·(u - plane[0]) + plane[4]·(v - plane[1]): about a corner, so
    /// that far from the origin no large terms cancel.
    plane: [f64; 5],
}

impl Footprint {
    /// None when the triangle is edge-on along t.
    fn new(tri: &[[f64; 3]; 3]) -> Option<Footprint> {
        let [p, q, r] = tri.map(DVec3::from_array);
        let normal = (q - p).cross(r - p);
        if normal.z == 0.0 || !normal.is_finite() {
            return None;
        }
        let side = normal.z.signum();
        let edges = [(p, q), (q, r), (r, p)].map(|(a, b)| {
            let (du, dv) = (b.x - a.x, b.y - a.y);
            [-dv * side, du * side, (dv * a.x - du * a.y) * side]
        });
        let plane = [p.x, p.y, p.z, -normal.x / normal.z, -normal.y / normal.z];
        Some(Footprint { edges, plane })
    }

    /// The lowest and highest t over `cell` ([u range, v range]) when the footprint holds the
    /// whole cell: the plane's at its corners.
    fn heights_over(&self, cell: [[f64; 2]; 2]) -> Option<(f64, f64)> {
        let corners = [
            (cell[0][0], cell[1][0]),
            (cell[0][1], cell[1][0]),
            (cell[0][0], cell[1][1]),
            (cell[0][1], cell[1][1]),
        ];
        let holds = |(u, v): (f64, f64)| self.edges.iter().all(|e| e[0] * u + e[1] * v + e[2] >= 0.0);
        if !corners.iter().all(|&c| holds(c)) {
            return None;
        }
        let [u0, v0, t0, du, dv] = self.plane;
        let t = corners.map(|(u, v)| t0 + du * (u - u0) + dv * (v - v0));
        Some((
            t.into_iter().fold(f64::INFINITY, f64::min),
            t.into_iter().fold(f64::NEG_INFINITY, f64::max),
        ))
    }
}

/// A convex polygon in (u, v, t), clipped by Sutherland–Hodgman: a triangle clipped by four
/// lines has at most seven corners.
#[derive(Clone, Copy)]
struct Polygon {
    corners: [[f64; 3]; 8],
    len: usize,
}

impl Polygon {
    fn triangle(tri: &[[f64; 3]; 3]) -> Polygon {
        let mut corners = [[0.0; 3]; 8];
        corners[..3].copy_from_slice(tri);
        Polygon { corners, len: 3 }
    }

    /// The part with coordinate `k` in the closed range `bounds`, if any. Inlined, so that each
    /// caller's axis `k` is a constant in the clipping loops.
    #[inline(always)]
    fn clip(&self, k: usize, bounds: [f64; 2]) -> Option<Polygon> {
        let lower = self.clip_side(k, bounds[0], true)?;
        lower.clip_side(k, bounds[1], false)
    }

    /// The part on one side of coordinate `k` = `bound`: where it is at least `bound` when
    /// `above`, else at most.
    #[inline(always)]
    fn clip_side(&self, k: usize, bound: f64, above: bool) -> Option<Polygon> {
        let mut out = Polygon {
            corners: [[0.0; 3]; 8],
            len: 0,
        };
        self.clipped_corners(k, bound, above, |p| {
            out.corners[out.len] = p;
            out.len += 1;
        });
        (out.len > 0).then_some(out)
    }

    /// Calls `corner` with each corner of [`Polygon::clip_side`]'s part, in order.
    #[inline(always)]
    fn clipped_corners(&self, k: usize, bound: f64, above: bool, mut corner: impl FnMut([f64; 3])) {
        let keeps = |p: &[f64; 3]| if above { p[k] >= bound } else { p[k] <= bound };
        let corners = &self.corners[..self.len];
        for i in 0..self.len {
            let (a, b) = (corners[i], corners[(i + 1) % self.len]);
            if keeps(&a) {
                corner(a);
            }
            if keeps(&a) != keeps(&b) {
                let s = (bound - a[k]) / (b[k] - a[k]);
                corner(std::array::from_fn(|j| {
                    if j == k { bound } else { a[j] + s * (b[j] - a[j]) }
                }));
            }
        }
    }

    /// The lowest and highest t of the part with coordinate `k` in the closed range `bounds`,
    /// if any: those of [`Polygon::clip`]'s corners, without building the last clip.
    #[inline(always)]
    fn heights_within(&self, k: usize, bounds: [f64; 2]) -> Option<(f64, f64)> {
        let (mut lo, mut hi, mut any) = (f64::INFINITY, f64::NEG_INFINITY, false);
        self.clip_side(k, bounds[0], true)?
            .clipped_corners(k, bounds[1], false, |p| {
                (lo, hi, any) = (lo.min(p[2]), hi.max(p[2]), true)
            });
        any.then_some((lo, hi))
    }
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

/// How far a plane's bound is from its best rectangle.
#[derive(Clone, Copy, PartialEq)]
enum Bound {
    /// The plane's open cells: no rectangle has more.
    Counted,
    /// The cells of a best that a taken rectangle has since closed a cell of.
    Stale,
    /// The cells of `best`, searched over the cells open now.
    Exact,
}

/// Where one candidate plane is open, a bit per cell of the axis grid, and the largest
/// rectangle of those cells.
struct PlaneCells {
    t: f64,
    open: Vec<u64>,
    best: Option<CellRect>,
    /// An upper bound on the cells of the largest open rectangle; exact when `state` says so.
    bound: usize,
    state: Bound,
    /// The search, over the bounding box of the cells open when it first ran (from the corner
    /// given), and the first of its rows where a cell has closed since it last ran.
    sweep: Option<([usize; 2], Sweep)>,
    dirty_from: usize,
}

/// The candidate planes of one axis grid, and which of them each gap holds.
struct Planes {
    list: Vec<PlaneCells>,
    /// Plane indices in order of height, and the heights in that order.
    order: Vec<usize>,
    heights: Vec<f64>,
    margin: f64,
    /// Cells along the grid's second axis, and words of a row of `open`.
    nv: usize,
    row_words: usize,
}

impl Planes {
    /// Each plane open in the cells with a gap that holds it: one pass over the gaps, since a
    /// gap holds a run of planes in order of height, and a cell's gaps do not overlap.
    fn new(gaps: &[Vec<Gap>], planes: &[f64], margin: f64, dims: [usize; 2]) -> Planes {
        let mut order: Vec<usize> = (0..planes.len()).collect();
        order.sort_by(|&a, &b| planes[a].total_cmp(&planes[b]));
        let heights = order.iter().map(|&i| planes[i]).collect();
        let row_words = dims[1].div_ceil(64);
        let list = planes
            .iter()
            .map(|&t| PlaneCells {
                t,
                open: vec![0; dims[0] * row_words],
                best: None,
                bound: 0,
                state: Bound::Counted,
                sweep: None,
                dirty_from: 0,
            })
            .collect();
        let mut all = Planes {
            list,
            order,
            heights,
            margin,
            nv: dims[1],
            row_words,
        };
        for (c, cell_gaps) in gaps.iter().enumerate() {
            for gap in cell_gaps {
                let (word, bit) = all.bit(c);
                for k in all.holding(gap) {
                    let plane = &mut all.list[all.order[k]];
                    plane.open[word] |= bit;
                    plane.bound += 1;
                }
            }
        }
        all
    }

    /// The word of `open` and the bit in it of cell `c`.
    fn bit(&self, c: usize) -> (usize, u64) {
        let (u, v) = (c / self.nv, c % self.nv);
        (u * self.row_words + v / 64, 1 << (v % 64))
    }

    /// The planes, as positions in `order`, that `gap` holds with `margin` to spare.
    fn holding(&self, gap: &Gap) -> std::ops::Range<usize> {
        let first = self.heights.partition_point(|&t| t <= gap.lo + self.margin);
        let end = self.heights.partition_point(|&t| t < gap.hi - self.margin);
        first..end.max(first)
    }

    /// Closes cell `c` on every plane its `gap` holds: a quad now fills that gap there. A plane
    /// whose best rectangle held the cell has only a bound left.
    fn close(&mut self, c: usize, gap: &Gap) {
        let (word, bit) = self.bit(c);
        let (u, v) = (c / self.nv, c % self.nv);
        for k in self.holding(gap) {
            let plane = &mut self.list[self.order[k]];
            plane.open[word] &= !bit;
            if let Some(([u0, _], _)) = plane.sweep {
                plane.dirty_from = plane.dirty_from.min(u - u0);
            }
            let holds = |r: &CellRect| (r.u[0]..r.u[1]).contains(&u) && (r.v[0]..r.v[1]).contains(&v);
            if plane.best.as_ref().is_some_and(holds) {
                plane.state = Bound::Stale;
            }
        }
    }

    /// Searches plane `i`'s open cells for its best rectangle: over their bounding box, then
    /// again only from the first row where a cell closed, until the open cells fit in half
    /// that box, when the search starts anew over their box.
    fn search(&mut self, i: usize) {
        let row_words = self.row_words;
        let plane = &mut self.list[i];
        match open_bounds(&plane.open, row_words) {
            None => plane.sweep = None,
            Some((lo, hi)) => {
                // From a whole word, so that the sweep reads the bits as they lie.
                let lo = [lo[0], lo[1] / 64 * 64];
                let (rows, columns) = (hi[0] + 1 - lo[0], hi[1] + 1 - lo[1]);
                if plane
                    .sweep
                    .as_ref()
                    .is_none_or(|(_, sweep)| 2 * rows * columns <= sweep.cells())
                {
                    plane.sweep = Some((lo, Sweep::new(rows, columns, MIN_SIDE)));
                    plane.dirty_from = 0;
                }
            }
        }
        plane.best = plane.sweep.as_mut().and_then(|([u0, v0], sweep)| {
            let first = *u0 * row_words + *v0 / 64;
            sweep
                .run(plane.dirty_from, &plane.open[first..], row_words)
                .filter(|r| r.cells() >= MIN_CELLS)
                .map(|r| CellRect {
                    u: r.u.map(|u| u + *u0),
                    v: r.v.map(|v| v + *v0),
                })
        });
        plane.dirty_from = usize::MAX;
        plane.bound = plane.best.map_or(0, |r| r.cells());
        plane.state = Bound::Exact;
    }
}

/// The first and last rows and columns with an open cell, if any.
fn open_bounds(open: &[u64], row_words: usize) -> Option<([usize; 2], [usize; 2])> {
    let rows: Vec<usize> = (0..open.len() / row_words)
        .filter(|&u| open[u * row_words..(u + 1) * row_words].iter().any(|&w| w != 0))
        .collect();
    let mut columns = vec![0u64; row_words];
    for &u in &rows {
        for (any, word) in columns.iter_mut().zip(&open[u * row_words..]) {
            *any |= word;
        }
    }
    let (a, b) = (
        columns.iter().position(|&w| w != 0)?,
        columns.iter().rposition(|&w| w != 0)?,
    );
    let v0 = a * 64 + columns[a].trailing_zeros() as usize;
    let v1 = b * 64 + 63 - columns[b].leading_zeros() as usize;
    Some(([*rows.first()?, v0], [*rows.last()?, v1]))
}

/// Greedy: the largest open rectangle over all candidate planes, then the next on what is left.
/// A plane is searched only once an upper bound on its rectangle leads all others: its open
/// cells at first; after a taken rectangle closes a cell of its best, that best. These are lazy
/// greedy picks, the same as searching every plane at first and again whenever it loses cells.
fn best_rectangles(g: &AxisGrid, gaps: &[Vec<Gap>], planes: &[f64], margin: f64) -> Vec<Panel> {
    let nv = g.dims[1];
    let mut planes = Planes::new(gaps, planes, margin, g.dims);
    let mut quads = Vec::new();
    while quads.len() < MAX_PER_AXIS {
        let candidates = &planes.list;
        let Some(top) = (0..candidates.len())
            .filter(|&i| candidates[i].bound > 0)
            .max_by(|&a, &b| {
                let (a, b) = (&candidates[a], &candidates[b]);
                a.bound.cmp(&b.bound).then(b.t.total_cmp(&a.t))
            })
        else {
            break;
        };
        if candidates[top].state != Bound::Exact {
            planes.search(top);
            continue;
        }
        let (rect, plane) = (
            candidates[top].best.expect("an exact bound counts its best"),
            candidates[top].t,
        );
        // Centre the quad in the heights that every cell of the rectangle leaves open.
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for (u, v) in rect.iter() {
            let c = u * nv + v;
            let gap = gaps[c]
                .iter()
                .find(|gap| gap.holds(plane, margin))
                .expect("the rectangle's cells hold the plane");
            lo = lo.max(gap.lo);
            hi = hi.min(gap.hi);
            planes.close(c, gap);
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
