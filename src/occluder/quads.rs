//! In-solid quads, after Voxel Farm's occluder quads: rectangles on planes that lie inside the
//! solid over their whole area. They cover walls far thinner than a voxel, because the search
//! runs on a 2D grid per axis that can be much finer than the 3D one.
//!
//! For each axis of a frame, each cell of a 2D grid over the other two axes is a prism along the
//! axis. Every triangle that meets the prism, clipped to it, blocks the range of heights it spans
//! there. Between two blocked ranges the prism's cross-section meets no surface, so it is inside
//! or outside as a whole, and one point query decides which: on a closed surface, the crossings
//! of the cell's centre line above the gap, since they count the same in every direction; and
//! as gaps of cells side by side that overlap in height meet, one query decides all that meet. A
//! plane is open in a cell when it lies in such an inside gap; a quad is a rectangle of cells in
//! which one plane is open. The test holds for the cell's whole footprint, not only at a
//! sample, so the quad is inside everywhere.
//!
//! Besides the world axes, frames turned by 45° about each axis give diagonal quads, which cover
//! what oblique views see of rounded shapes.

use super::rectangle::{CellRect, Sweep};
use super::{Panel, Shape, WorldBox};
use crate::geom::grid_counts::GridCounts;
use crate::geom::{ceil_index, f32_slack, floor_index, greater, index_to_f64, lesser};
use crate::mesh::buckets::Buckets;
use crate::mesh::{Mesh, point_bounds};
use crate::voxel::columns::column_sign;
use glam::{DMat3, DQuat, DVec3};
use rayon::prelude::*;
use std::cmp::{Ordering, Reverse};
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
    /// Whether a plane at height `t` lies in it with `margin` to spare.
    fn holds(&self, t: f64, margin: f64) -> bool {
        self.lo + margin < t && t < self.hi - margin
    }

    /// The planes at `heights`, in order, that it holds with `margin` to spare: a run of them,
    /// as positions in `heights`.
    fn holds_among(&self, heights: &[f64], margin: f64) -> std::ops::Range<usize> {
        let first = heights.partition_point(|&t| t <= self.lo + margin);
        let end = heights.partition_point(|&t| t < self.hi - margin);
        first..end.max(first)
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

    /// The line before cell `index` along grid axis k: one expression for the quads' corners
    /// and the blocked heights' clip lines, so that both see the same values.
    fn line(&self, k: usize, index: usize) -> f64 {
        self.origin[k] + index_to_f64(index) * self.cell
    }

    /// Coordinate x along grid axis k in cells from the origin. Rounding keeps its order, so
    /// the least of several coordinates gives the least of theirs.
    fn cells_along(&self, k: usize, x: f64) -> f64 {
        (x - self.origin[k]) / self.cell
    }

    /// The centre of cell (u, v) in grid coordinates.
    fn center(&self, u: usize, v: usize) -> [f64; 2] {
        [
            self.origin[0] + (index_to_f64(u) + 0.5) * self.cell,
            self.origin[1] + (index_to_f64(v) + 0.5) * self.cell,
        ]
    }

    /// A grid point's place among the cells: its first two coordinates in cells from the origin.
    fn place_of(&self, p: &[f64; 3]) -> [f64; 2] {
        [self.cells_along(0, p[0]), self.cells_along(1, p[1])]
    }

    /// Cells whose closed footprint meets the bounds of `places` along grid axis k.
    fn range_of(&self, k: usize, places: &[[f64; 2]; 3]) -> std::ops::Range<usize> {
        let (lo, hi) = places.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lesser(lo, p[k]), greater(hi, p[k]))
        });
        let a = ceil_index(lo - 1.0);
        let b = match hi {
            f if f < 0.0 => 0,
            f => (floor_index(f) + 1).min(self.dims[k]),
        };
        a.min(b)..b
    }

    /// The lines along grid axis k (as indices for [`AxisGrid::line`]) within [lo, hi], in
    /// cells from the origin ([`AxisGrid::cells_along`]), give or take rounding. Without
    /// rounding calls: the coordinates are never below the origin.
    fn lines_within(&self, k: usize, lo: f64, hi: f64) -> std::ops::Range<usize> {
        self.lines_from_floors(k, (floor_index(lo), lo), floor_index(hi))
    }

    /// [`AxisGrid::lines_within`] from the floors of the bounds, where they are known: the
    /// lower bound as (its floor, itself), the upper as its floor.
    fn lines_from_floors(&self, k: usize, lo: (usize, f64), hi_floor: usize) -> std::ops::Range<usize> {
        lo.0 + usize::from(index_to_f64(lo.0) < lo.1)..hi_floor.min(self.dims[k]) + 1
    }
}

/// How a gap is told inside the solid or outside.
#[derive(Clone, Copy)]
pub enum Solid<'a> {
    /// A closed surface: the crossings of the cell's centre line above the gap's middle, whose
    /// signed sum is the winding number there and whose count's parity is the parity test, as
    /// along any other ray. Inside where the sum is at least 1, or with `parity`, the count odd.
    /// Asked once for each region of gaps that meet across the cells' sides, which no surface
    /// parts ([`inside_by_regions`]).
    Closed { parity: bool },
    /// Any other: the classification `at` a world point, asked at the gap's middle. It holds
    /// nowhere outside the boxes `within` (such as the inner voxels), so a cell whose centre
    /// line misses them all has no inside gap, and nothing in it is worked out.
    Points {
        at: &'a (dyn Fn(DVec3) -> bool + Sync),
        within: &'a [WorldBox],
    },
}

/// Quads inside the solid, up to `MAX_PER_AXIS` per axis and frame. `grid` is the number of
/// cells along the mesh's longest side.
pub fn find(mesh: &Mesh, grid: usize, solid: Solid) -> Vec<Panel> {
    let frames = [
        DQuat::IDENTITY,
        DQuat::from_rotation_x(FRAC_PI_4),
        DQuat::from_rotation_y(FRAC_PI_4),
        DQuat::from_rotation_z(FRAC_PI_4),
    ];
    let passes: Vec<(DQuat, usize)> = frames.iter().flat_map(|&f| (0..3).map(move |axis| (f, axis))).collect();
    let (world_lo, world_hi) = mesh.bounds();
    let inset = f32_slack(world_lo.as_dvec3(), world_hi.as_dvec3());
    // Each pass's gaps, then its rectangles: the searches, serial within a pass, are shared out
    // once all gaps are found, those with the most open cells first, as they mostly take
    // longest: a thread that ends one takes the next, and none waits long for the last.
    let mut found: Vec<_> = passes
        .par_iter()
        .enumerate()
        .filter_map(|(pass, &(turn, axis))| {
            let (lo, hi) = point_bounds(mesh.positions.iter().map(|p| turn * p.as_dvec3()));
            let size = (hi - lo).max_element();
            let cell = size / grid as f64;
            if cell <= 0.0 || !cell.is_finite() {
                return None;
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
            let margin = 1e-6 * size + inset;
            let corners: Vec<[f64; 3]> = mesh.positions.iter().map(|p| g.uv(p.as_dvec3())).collect();
            let reach = match solid {
                Solid::Points { within, .. } => Some(Reach::new(&g, within)),
                Solid::Closed { .. } => None,
            };
            let gaps = inside_gaps(mesh, &corners, &g, margin, solid, reach.as_ref());
            let planes = candidate_planes(&gaps, lo[axis], hi[axis], cell);
            let order = PlaneOrder::new(&gaps, &planes, margin);
            Some((order.open_cells(), pass, g, gaps, (planes, order), margin))
        })
        .collect();
    found.sort_by_key(|&(open, ..)| Reverse(open));
    let mut by_pass: Vec<(usize, Vec<Panel>)> = found
        .into_iter()
        .par_bridge()
        .map(|(_, pass, g, gaps, (planes, order), margin)| {
            (pass, best_rectangles(&g, &gaps, (&planes, order), margin, inset))
        })
        .collect();
    by_pass.sort_unstable_by_key(|&(pass, _)| pass);
    by_pass.into_iter().flat_map(|(_, quads)| quads).collect()
}

/// The cells of an axis grid whose centre lines meet any of some world boxes, give or take a
/// hundredth of a cell: all those where a classification that holds only within the boxes may
/// hold ([`Solid::Points`]).
struct Reach {
    /// Whether each cell is reached, the second axis fastest.
    reached: Vec<bool>,
    cells_along_v: usize,
    /// How many cells are reached over rectangles of cells.
    counts: GridCounts,
}

impl Reach {
    fn new(g: &AxisGrid, boxes: &[WorldBox]) -> Reach {
        let [nu, nv] = g.dims;
        let mut reached = vec![false; nu * nv];
        // A box's extent in the frame, about its centre: the turn's entries' sizes weigh its
        // half sides.
        let sizes = DMat3::from_quat(g.turn).abs();
        let (ua, va) = ((g.axis + 1) % 3, (g.axis + 2) % 3);
        for b in boxes {
            let (centre, half) = (g.turn * (0.5 * (b.lo() + b.hi())), sizes * (0.5 * (b.hi() - b.lo())));
            let cells = |k: usize, along: usize| {
                let slack = 0.01 * g.cell + 1e-9 * (centre[along].abs() + half[along]);
                let (lo, hi) = (centre[along] - half[along] - slack, centre[along] + half[along] + slack);
                // Cells whose centres, (i + 0.5) cells from the origin, lie in [lo, hi].
                let first = (g.cells_along(k, lo) - 0.5).ceil().max(0.0);
                let last = (g.cells_along(k, hi) - 0.5).floor().min(g.dims[k] as f64 - 1.0);
                (first <= last).then(|| first as usize..last as usize + 1)
            };
            if let (Some(us), Some(vs)) = (cells(0, ua), cells(1, va)) {
                for u in us {
                    reached[u * nv + vs.start..u * nv + vs.end].fill(true);
                }
            }
        }
        Reach {
            counts: GridCounts::new(&reached, nu, nv),
            reached,
            cells_along_v: nv,
        }
    }

    /// Whether any of the cells `us` × `vs` is reached.
    fn any(&self, us: &std::ops::Range<usize>, vs: &std::ops::Range<usize>) -> bool {
        self.counts.count(us.clone(), vs.clone()) > 0
    }

    fn holds(&self, u: usize, v: usize) -> bool {
        self.reached[u * self.cells_along_v + v]
    }
}

/// For every cell, the gaps between blocked height ranges whose cross-section is inside.
/// `corners` are the mesh's vertices in grid coordinates. Only cells `reach` holds, if given,
/// may have any.
fn inside_gaps(
    mesh: &Mesh,
    corners: &[[f64; 3]],
    g: &AxisGrid,
    margin: f64,
    solid: Solid,
    reach: Option<&Reach>,
) -> Gaps {
    let nv = g.dims[1];
    let cells = g.dims[0] * nv;
    let blocked = blocked_ranges(mesh, corners, g, reach);
    let Buckets {
        starts,
        items: mut ranges,
    } = Buckets::new(
        cells,
        blocked.iter().flatten().map(|&block| (block.cell as usize, block)),
    );
    // A row of cells at a time: few allocations, and enough rows to share out.
    let mut rows: Vec<&mut [Block]> = Vec::with_capacity(g.dims[0]);
    let mut rest = ranges.as_mut_slice();
    for u in 0..g.dims[0] {
        let (head, tail) = rest.split_at_mut(starts[(u + 1) * nv] - starts[u * nv]);
        rows.push(head);
        rest = tail;
    }
    // Each row's gaps, and for a closed surface, the index among their cell's blocks of the
    // first block above each: it decides them once per region below.
    let by_row: Vec<(Vec<Gap>, Vec<usize>, Vec<u32>)> = rows
        .into_par_iter()
        .enumerate()
        .map(|(u, row)| {
            // Room for a gap a cell, about what a row has.
            let (mut list, mut ends, mut above) = (Vec::with_capacity(nv), Vec::with_capacity(nv), Vec::new());
            let mut found = Vec::new();
            for v in 0..nv {
                let c = u * nv + v;
                let ranges = &mut row[starts[c] - starts[u * nv]..starts[c + 1] - starts[u * nv]];
                // The heights are finite, as the mesh's corners are (MAX_COORDINATE): the plain
                // compare, cheaper than total_cmp's.
                ranges.sort_unstable_by(|a, b| a.heights.0.partial_cmp(&b.heights.0).unwrap_or(Ordering::Equal));
                // The gaps, each with the index of the first block above it.
                found.clear();
                let mut top = f64::NEG_INFINITY;
                for (k, block) in ranges.iter().enumerate() {
                    let (t0, t1) = block.heights;
                    if top > f64::NEG_INFINITY && t0 - top > 2.0 * margin {
                        found.push((k, Gap { lo: top, hi: t0 }));
                    }
                    top = greater(top, t1);
                }
                match solid {
                    Solid::Points { at, .. } => {
                        let [cu, cv] = g.center(u, v);
                        let inside = |gap: &Gap| at(g.point(cu, cv, 0.5 * (gap.lo + gap.hi)));
                        list.extend(found.iter().map(|(_, gap)| *gap).filter(inside));
                    }
                    Solid::Closed { .. } => {
                        list.extend(found.iter().map(|(_, gap)| *gap));
                        above.extend(found.iter().map(|&(k, _)| k as u32));
                    }
                }
                ends.push(list.len());
            }
            (list, ends, above)
        })
        .collect();
    let mut gaps = Gaps {
        starts: Vec::with_capacity(cells + 1),
        list: Vec::new(),
    };
    gaps.starts.push(0);
    let mut above = Vec::new();
    for (list, ends, row_above) in by_row {
        let before = gaps.list.len();
        gaps.starts.extend(ends.iter().map(|end| before + end));
        gaps.list.extend(list);
        above.extend(row_above);
    }
    if let Solid::Closed { parity } = solid {
        let inside = inside_by_regions(&gaps, nv, margin, |c, gap| {
            let blocks = &ranges[starts[c]..starts[c + 1]];
            let tri = |block: &Block| mesh.triangles[block.triangle as usize].map(|i| corners[i as usize]);
            let center = g.center(c / nv, c % nv);
            let [sum, count] = crossings_above(blocks, above[gap] as usize, |block| column_sign(&tri(block), center));
            if parity { count % 2 == 1 } else { sum >= 1 }
        });
        gaps.keep(&inside);
    }
    gaps
}

/// The signed sum and the count of a cell's centre line's crossings above one of its gaps:
/// `blocks` are the cell's, sorted by lowest height, and `first_above` is the index of the
/// first above the gap. `crossing` gives a block's sign where the line crosses its triangle. As
/// all of them cancel out, those below, negated, serve as well: the side with fewer blocks is
/// counted.
fn crossings_above(blocks: &[Block], first_above: usize, crossing: impl Fn(&Block) -> Option<i8>) -> [i32; 2] {
    let count = |side: &[Block]| {
        let signs = side.iter().filter_map(&crossing);
        signs.fold([0, 0], |[sum, count], sign| [sum + i32::from(sign), count + 1])
    };
    if blocks.len() - first_above <= first_above {
        count(&blocks[first_above..])
    } else {
        let [below, n] = count(&blocks[..first_above]);
        [-below, n]
    }
}

/// Whether each gap is inside, `decide` asked for one gap (its cell and index) of each region
/// of them: gaps of cells side by side that overlap by more than `2 * margin` in height meet,
/// as the cells' cross-sections there meet no surface and share a side. Across a closed
/// surface alone does the winding number or the parity change, so a region's gaps agree.
fn inside_by_regions(gaps: &Gaps, nv: usize, margin: f64, decide: impl Fn(usize, usize) -> bool) -> Vec<bool> {
    let mut regions = Regions::new(gaps.list.len());
    for c in 0..gaps.starts.len() - 1 {
        let beside = [(c % nv > 0).then(|| c - 1), c.checked_sub(nv)];
        for other in beside.into_iter().flatten() {
            let (mut i, mut j) = (gaps.starts[c], gaps.starts[other]);
            // Each cell's gaps are in order of height and apart.
            while i < gaps.starts[c + 1] && j < gaps.starts[other + 1] {
                let (a, b) = (gaps.list[i], gaps.list[j]);
                if lesser(a.hi, b.hi) - greater(a.lo, b.lo) > 2.0 * margin {
                    regions.join(i, j);
                }
                if a.hi < b.hi {
                    i += 1;
                } else {
                    j += 1;
                }
            }
        }
    }
    let mut decided = vec![None; gaps.list.len()];
    let mut inside = Vec::with_capacity(gaps.list.len());
    for c in 0..gaps.starts.len() - 1 {
        for gap in gaps.starts[c]..gaps.starts[c + 1] {
            inside.push(*decided[regions.root(gap)].get_or_insert_with(|| decide(c, gap)));
        }
    }
    inside
}

/// Sets of gaps that meet, each named by one of them (union-find, with path halving).
struct Regions {
    parent: Vec<u32>,
}

impl Regions {
    fn new(count: usize) -> Regions {
        Regions {
            parent: (0..count as u32).collect(),
        }
    }

    fn root(&mut self, mut i: usize) -> usize {
        while self.parent[i] as usize != i {
            let grand = self.parent[self.parent[i] as usize];
            self.parent[i] = grand;
            i = grand as usize;
        }
        i
    }

    fn join(&mut self, a: usize, b: usize) {
        let (a, b) = (self.root(a), self.root(b));
        self.parent[a.max(b)] = a.min(b) as u32;
    }
}

/// The range of heights a triangle blocks in a cell.
#[derive(Clone, Copy, Default)]
struct Block {
    cell: u32,
    triangle: u32,
    heights: (f64, f64),
}

/// Triangles in each share of [`blocked_ranges`], and the blocks its list has room for at first
/// per triangle, about what a triangle makes: a list that outgrows its room is copied.
const TRIANGLES_PER_SHARE: usize = 1024;
const BLOCKS_PER_TRIANGLE: usize = 8;

/// The heights each triangle blocks in each cell whose closed footprint it meets (of those
/// `reach` holds, if given), by cell: in one list per share of the triangles, which the
/// counting sort reads without joining them.
fn blocked_ranges(mesh: &Mesh, corners: &[[f64; 3]], g: &AxisGrid, reach: Option<&Reach>) -> Vec<Vec<Block>> {
    let nv = g.dims[1];
    // Each corner's place among the cells, once rather than in each of its triangles.
    let in_cells: Vec<[f64; 2]> = corners.iter().map(|p| g.place_of(p)).collect();
    let count = mesh.triangles.len();
    (0..count.div_ceil(TRIANGLES_PER_SHARE))
        .into_par_iter()
        .map(|share| {
            let triangles = share * TRIANGLES_PER_SHARE..count.min((share + 1) * TRIANGLES_PER_SHARE);
            let mut out = Vec::with_capacity(triangles.len() * BLOCKS_PER_TRIANGLE);
            let mut cells = CellHeights::default();
            for t in triangles {
                let tri = mesh.triangles[t].map(|i| corners[i as usize]);
                let places = mesh.triangles[t].map(|i| in_cells[i as usize]);
                let block = |c: usize, heights| Block {
                    cell: c as u32,
                    triangle: t as u32,
                    heights,
                };
                let lo = |k: usize| tri.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
                let hi = |k: usize| tri.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
                let (ru, rv) = (g.range_of(0, &places), g.range_of(1, &places));
                if reach.is_some_and(|reach| !reach.any(&ru, &rv)) {
                    continue;
                }
                if ru.len() == 1 && rv.len() == 1 {
                    // Wholly inside one cell.
                    out.push(block(ru.start * nv + rv.start, (lo(2), hi(2))));
                    continue;
                }
                cells.of_triangle(&tri, &places, g, [ru.start, rv.start], [ru.len(), rv.len()]);
                for (u, row) in ru.zip(cells.heights.chunks(rv.len() + 2).skip(1)) {
                    for (v, &(t0, t1)) in rv.clone().zip(&row[1..]) {
                        if t0 <= t1 && reach.is_none_or(|reach| reach.holds(u, v)) {
                            out.push(block(u * nv + v, (t0, t1)));
                        }
                    }
                }
            }
            out
        })
        .collect()
}

/// The lowest and highest height of a triangle (in grid coordinates) over each cell of a block
/// of cells, with what finding them needs, kept from triangle to triangle.
#[derive(Default)]
struct CellHeights {
    /// Over the block and a border of one cell around it, the second axis fastest: lowest above
    /// highest where the triangle misses the cell. The border takes what falls just outside.
    heights: Vec<(f64, f64)>,
    /// The block's first cell and its cells along each axis.
    first: [usize; 2],
    cells: [usize; 2],
    /// Where the triangle crosses each line between cells along the first axis, from the
    /// block's first on: its points of lowest and highest second coordinate, as (v, t); the
    /// lowest above the highest where it crosses none.
    sections: Vec<[(f64, f64); 2]>,
}

/// The cells along one axis whose closed footprints hold a point: the first, as its place in
/// the bordered block, and whether the next holds it too (on the line between them).
type Along = (usize, bool);

impl CellHeights {
    /// The heights of `tri` over the cells from `first`, `cells` along each axis: those whose
    /// closed footprints its bounds meet; `places` are its corners' ([`AxisGrid::place_of`]).
    /// Over a cell, the height is linear on the part of the triangle in it, so its extremes lie
    /// at that part's corners: the triangle's own corners, where its edges cross the lines
    /// between cells, and where two such lines cross inside it. Each of those points counts in
    /// every cell whose closed footprint holds it.
    fn of_triangle(
        &mut self,
        tri: &[[f64; 3]; 3],
        places: &[[f64; 2]; 3],
        g: &AxisGrid,
        first: [usize; 2],
        cells: [usize; 2],
    ) {
        self.heights.clear();
        self.heights
            .resize((cells[0] + 2) * (cells[1] + 2), (f64::INFINITY, f64::NEG_INFINITY));
        self.sections.clear();
        self.sections
            .resize(cells[0] + 1, [(f64::INFINITY, 0.0), (f64::NEG_INFINITY, 0.0)]);
        (self.first, self.cells) = (first, cells);
        // Each corner's line at or below it along each axis, for its own cells and for the
        // lines its edges cross.
        let floors = places.map(|p| p.map(floor_index));
        for i in 0..3 {
            let along = |k: usize| self.at_floor(k, floors[i][k], places[i][k]);
            self.add(along(0), along(1), tri[i][2]);
        }
        for k in 0..2 {
            let other = 1 - k;
            for i in 0..3 {
                let j = (i + 1) % 3;
                let (a, b) = (tri[i], tri[j]);
                if a[k] == b[k] {
                    continue;
                }
                let (lo, hi) = if a[k] < b[k] { (i, j) } else { (j, i) };
                for line in g.lines_from_floors(k, (floors[lo][k], places[lo][k]), floors[hi][k]) {
                    let s = (g.line(k, line) - a[k]) / (b[k] - a[k]);
                    let (y, t) = (a[other] + s * (b[other] - a[other]), a[2] + s * (b[2] - a[2]));
                    let (across, along) = (self.on_line(k, line), self.at(other, g.cells_along(other, y)));
                    if k == 1 {
                        self.add(along, across, t);
                        continue;
                    }
                    self.add(across, along, t);
                    if let Some([low, high]) = self.sections.get_mut(line.wrapping_sub(first[0])) {
                        if y < low.0 {
                            *low = (y, t);
                        }
                        if y > high.0 {
                            *high = (y, t);
                        }
                    }
                }
            }
        }
        // Where the triangle's section along a line of the first axis crosses the lines of
        // the second: the corners of four cells.
        let sections = std::mem::take(&mut self.sections);
        for (k, &[(v0, t0), (v1, t1)]) in sections.iter().enumerate() {
            if v0 > v1 {
                continue;
            }
            let across = self.on_line(0, first[0] + k);
            for line in g.lines_within(1, g.cells_along(1, v0), g.cells_along(1, v1)) {
                let v = g.line(1, line);
                if v0 < v && v < v1 {
                    let t = t0 + (v - v0) * ((t1 - t0) / (v1 - v0));
                    self.add(across, self.on_line(1, line), t);
                }
            }
        }
        self.sections = sections;
    }

    /// The cells along grid axis k whose closed footprints hold the point `f` cells from the
    /// origin (never below it): cell f, and the one before where f lies on the line between.
    fn at(&self, k: usize, f: f64) -> Along {
        self.at_floor(k, floor_index(f), f)
    }

    /// [`CellHeights::at`] for `f` whose floor is `i`.
    fn at_floor(&self, k: usize, i: usize, f: f64) -> Along {
        let on_line = index_to_f64(i) == f;
        self.place(k, i + 1 - usize::from(on_line), on_line)
    }

    /// The two cells along axis k on either side of line `line`.
    fn on_line(&self, k: usize, line: usize) -> Along {
        self.place(k, line, true)
    }

    /// Cell `cell_plus_one - 1` along axis k, and the next when `two`, as places in the
    /// bordered block (whose place 0 is the border before its first cell): within the block
    /// and its border whatever rounding did.
    fn place(&self, k: usize, cell_plus_one: usize, two: bool) -> Along {
        (cell_plus_one.saturating_sub(self.first[k]).min(self.cells[k]), two)
    }

    /// Counts height `t` in the cells `u` × `v`.
    fn add(&mut self, u: Along, v: Along, t: f64) {
        let width = self.cells[1] + 2;
        let at = u.0 * width + v.0;
        let mut put = |i: usize| {
            let h = &mut self.heights[i];
            *h = (lesser(h.0, t), greater(h.1, t));
        };
        put(at);
        if v.1 {
            put(at + 1);
        }
        if u.1 {
            put(at + width);
            if v.1 {
                put(at + width + 1);
            }
        }
    }
}

/// Each cell's inside gaps, in order of height: cell c's are `list[starts[c]..starts[c + 1]]`.
struct Gaps {
    starts: Vec<usize>,
    list: Vec<Gap>,
}

impl Gaps {
    fn of(&self, c: usize) -> &[Gap] {
        &self.list[self.starts[c]..self.starts[c + 1]]
    }

    /// Keeps the gaps `keep` holds, one flag a gap.
    fn keep(&mut self, keep: &[bool]) {
        let mut kept = 0;
        for c in 0..self.starts.len() - 1 {
            let (first, end) = (self.starts[c], self.starts[c + 1]);
            self.starts[c] = kept;
            kept += keep[first..end].iter().filter(|&&k| k).count();
        }
        *self.starts.last_mut().expect("a start past the last cell") = kept;
        let mut flags = keep.iter();
        self.list.retain(|_| *flags.next().expect("a flag a gap"));
    }
}

/// Planes worth trying: evenly spaced along the axis, plus the middles of the thin gaps
/// (walls thinner than a cell) that many cells share.
fn candidate_planes(gaps: &Gaps, lo: f64, hi: f64, cell: f64) -> Vec<f64> {
    let step = PLANE_SPACING * cell;
    let steps = ((hi - lo) / step).ceil().max(1.0) as usize;
    let mut planes: Vec<f64> = (0..steps).map(|k| lo + (k as f64 + 0.5) * step).collect();
    let quantum = cell / 64.0;
    let mut thin: HashMap<i64, (usize, f64)> = HashMap::new();
    for gap in gaps.list.iter().filter(|g| g.hi - g.lo < 2.0 * cell) {
        let mid = 0.5 * (gap.lo + gap.hi);
        let entry = thin.entry((mid / quantum).round() as i64).or_insert((0, mid));
        entry.0 += 1;
    }
    let mut thin: Vec<(usize, f64)> = thin.into_values().collect();
    thin.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.total_cmp(&b.1)));
    planes.extend(thin.iter().take(MAX_GAP_PLANES).map(|&(_, mid)| mid));
    planes
}

/// The candidate planes in order of height, and the run of them that each gap holds.
struct PlaneOrder {
    /// Plane indices in order of height, and each plane's position in it.
    by_height: Vec<usize>,
    rank: Vec<usize>,
    /// The planes, as positions in `by_height`, that each gap holds ([`Gap::holds_among`]), in the
    /// order of [`Gaps::list`].
    held: Vec<std::ops::Range<usize>>,
}

impl PlaneOrder {
    fn new(gaps: &Gaps, planes: &[f64], margin: f64) -> PlaneOrder {
        let mut by_height: Vec<usize> = (0..planes.len()).collect();
        by_height.sort_by(|&a, &b| planes[a].total_cmp(&planes[b]));
        let heights: Vec<f64> = by_height.iter().map(|&i| planes[i]).collect();
        let mut rank = vec![0; planes.len()];
        for (k, &i) in by_height.iter().enumerate() {
            rank[i] = k;
        }
        let held = gaps.list.iter().map(|gap| gap.holds_among(&heights, margin)).collect();
        PlaneOrder { by_height, rank, held }
    }

    /// The cells open over all planes, as [`Planes::new`] opens them: what a pass's rectangle
    /// search mostly takes its time over.
    fn open_cells(&self) -> usize {
        self.held.iter().map(|held| held.len()).sum()
    }
}

/// How far a plane's bound is from its best rectangle.
#[derive(Clone, Copy, PartialEq)]
enum Bound {
    /// At most its open cells, or the cells of a best that a taken rectangle has since closed
    /// a cell of.
    Counted,
    /// Also at most what the runs of cells open in its pairs of rows allow ([`runs_bound`]),
    /// over the cells open now.
    Runs,
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
    /// How many of its cells are open.
    open_cells: usize,
    /// The search, over the bounding box of the cells open when it first ran (from the corner
    /// given), and its rows from the first to past the last where cells closed since it last
    /// ran: all of them before it first runs.
    sweep: Option<([usize; 2], Sweep)>,
    dirty: Option<std::ops::Range<usize>>,
    /// The longest run of cells open in both rows of each pair of rows next to each other
    /// (pair u: rows u and u + 1; none past the last row), as [`runs_bound`] last read them,
    /// and the pairs with a row where cells closed since: all of them before it first runs.
    pair_runs: Vec<usize>,
    stale_pairs: Option<std::ops::Range<usize>>,
}

/// The candidate planes of one axis grid, and which of them each gap holds.
struct Planes {
    list: Vec<PlaneCells>,
    order: PlaneOrder,
    /// Cells along the grid's second axis, and words of a row of `open`.
    nv: usize,
    row_words: usize,
}

impl Planes {
    /// Each plane open in the cells with a gap that holds it: a gap holds a run of planes in
    /// order of height, and a cell's gaps do not overlap.
    fn new(gaps: &Gaps, (planes, order): (&[f64], PlaneOrder), dims: [usize; 2]) -> Planes {
        let row_words = dims[1].div_ceil(64);
        let list = planes
            .iter()
            .map(|&t| PlaneCells {
                t,
                open: vec![0; dims[0] * row_words],
                best: None,
                bound: 0,
                state: Bound::Counted,
                open_cells: 0,
                sweep: None,
                dirty: None,
                pair_runs: vec![0; dims[0]],
                stale_pairs: Some(0..dims[0]),
            })
            .collect();
        let mut all = Planes {
            list,
            order,
            nv: dims[1],
            row_words,
        };
        // Where each gap's run of planes starts and ends, by position in height; then the
        // cells open on each plane in turn, from those on the plane below.
        let mut opens = vec![Vec::new(); planes.len() + 1];
        let mut closes = vec![Vec::new(); planes.len() + 1];
        for c in 0..gaps.starts.len() - 1 {
            for held in &all.order.held[gaps.starts[c]..gaps.starts[c + 1]] {
                if !held.is_empty() {
                    opens[held.start].push(c);
                    closes[held.end].push(c);
                }
            }
        }
        let mut open = vec![0; dims[0] * row_words];
        for (k, (opening, closing)) in opens.iter().zip(&closes).take(planes.len()).enumerate() {
            // A cell's gaps do not overlap: one that ends here goes before one that starts.
            for &c in closing {
                let (word, bit) = all.bit(c);
                open[word] &= !bit;
            }
            for &c in opening {
                let (word, bit) = all.bit(c);
                open[word] |= bit;
            }
            let plane = &mut all.list[all.order.by_height[k]];
            plane.open.copy_from_slice(&open);
            plane.open_cells = open.iter().map(|w| w.count_ones() as usize).sum();
            plane.bound = plane.open_cells;
        }
        all
    }

    /// The word of `open` and the bit in it of cell `c`.
    fn bit(&self, c: usize) -> (usize, u64) {
        let (u, v) = (c / self.nv, c % self.nv);
        (u * self.row_words + v / 64, 1 << (v % 64))
    }

    /// Closes each cell of `rect` on every plane its gap holds, the gaps given by index in
    /// [`Gaps::list`] in the order of [`CellRect::iter`]: a quad now fills that gap there. A
    /// plane whose best rectangle held a closed cell has only a bound left. Row by row, the
    /// cells' runs of planes become a mask of cells for each plane in order of height.
    fn close(&mut self, rect: &CellRect, gaps: &[usize]) {
        let width = rect.v[1] - rect.v[0];
        let first_word = rect.v[0] / 64;
        let n = (rect.v[1] - 1) / 64 + 1 - first_word;
        // For each position in height order, the row's cells whose run of planes starts there and
        // those whose run ends there, `n` words each.
        let positions = self.order.by_height.len() + 1;
        let (mut starting, mut ending) = (vec![0u64; positions * n], vec![0u64; positions * n]);
        let mut mask = vec![0u64; n];
        for (u, row_gaps) in (rect.u[0]..rect.u[1]).zip(gaps.chunks(width)) {
            // The positions the row's runs span.
            let (mut lowest, mut end) = (positions, 0);
            for (v, &gap) in (rect.v[0]..rect.v[1]).zip(row_gaps) {
                let held = &self.order.held[gap];
                if !held.is_empty() {
                    let (word, bit) = (v / 64 - first_word, 1u64 << (v % 64));
                    starting[held.start * n + word] |= bit;
                    ending[held.end * n + word] |= bit;
                    (lowest, end) = (lowest.min(held.start), end.max(held.end));
                }
            }
            mask.fill(0);
            for k in lowest..end {
                let (starts, ends) = (&starting[k * n..(k + 1) * n], &ending[k * n..(k + 1) * n]);
                for ((m, s), e) in mask.iter_mut().zip(starts).zip(ends) {
                    *m = (*m | s) & !e;
                }
                if mask.iter().any(|&m| m != 0) {
                    self.close_row(self.order.by_height[k], u, first_word, &mask);
                }
            }
            if lowest < end {
                starting[lowest * n..(end + 1) * n].fill(0);
                ending[lowest * n..(end + 1) * n].fill(0);
            }
        }
    }

    /// Closes plane `i`'s cells of row `u` in `mask`, whose words start at word `first`.
    fn close_row(&mut self, i: usize, u: usize, first: usize, mask: &[u64]) {
        let plane = &mut self.list[i];
        let row = &mut plane.open[u * self.row_words + first..][..mask.len()];
        let mut closed = 0;
        let mut in_best = false;
        let best_columns = plane.best.filter(|r| (r.u[0]..r.u[1]).contains(&u)).map(|r| r.v);
        for (w, (word, &mask)) in row.iter_mut().zip(mask).enumerate() {
            let shut = *word & mask;
            if shut == 0 {
                continue;
            }
            *word &= !shut;
            closed += shut.count_ones() as usize;
            if let Some([v0, v1]) = best_columns {
                let columns = columns_before(64 * (first + w), v1) & !columns_before(64 * (first + w), v0);
                in_best |= shut & columns != 0;
            }
        }
        if closed == 0 {
            return;
        }
        plane.open_cells -= closed;
        widen(&mut plane.stale_pairs, u.saturating_sub(1)..u + 1);
        if let Some(([u0, _], _)) = plane.sweep {
            widen(&mut plane.dirty, u - u0..u - u0 + 1);
        }
        // A runs bound still holds, but one over the cells open now may be lower.
        if in_best || plane.state == Bound::Runs {
            plane.state = Bound::Counted;
        }
        if plane.state != Bound::Exact {
            plane.bound = plane.bound.min(plane.open_cells);
        }
    }

    /// Searches plane `i`'s open cells for its best rectangle: over their bounding box, then
    /// again over the rows where cells closed and those whose heights that changes, until the
    /// open cells fit in half that box, when the search starts anew over their box.
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
                    plane.dirty = Some(0..usize::MAX);
                }
            }
        }
        plane.best = plane.sweep.as_mut().and_then(|([u0, v0], sweep)| {
            let first = *u0 * row_words + *v0 / 64;
            sweep
                .run(plane.dirty.take().unwrap_or(0..0), &plane.open[first..], row_words)
                .filter(|r| r.cells() >= MIN_CELLS)
                .map(|r| CellRect {
                    u: r.u.map(|u| u + *u0),
                    v: r.v.map(|v| v + *v0),
                })
        });
        plane.bound = plane.best.map_or(0, |r| r.cells());
        plane.state = Bound::Exact;
        self.bound_subsets(i);
    }

    /// Bounds the planes next to plane `i` in height, while their open cells all lie among
    /// `i`'s, by `i`'s best: none of their rectangles is larger. Those with the same open cells
    /// take that best, as a search of theirs would find it; planes a few cells apart in a thick
    /// part of the solid often agree.
    fn bound_subsets(&mut self, i: usize) {
        let (k, best, rect) = (self.order.rank[i], self.list[i].bound, self.list[i].best);
        let (mut below, mut above) = ((0..k).rev(), k + 1..self.order.by_height.len());
        for side in [&mut below as &mut dyn Iterator<Item = usize>, &mut above] {
            for r in side {
                let j = self.order.by_height[r];
                let (open, around) = (&self.list[j].open, &self.list[i].open);
                if !open.iter().zip(around).all(|(a, b)| a & !b == 0) {
                    break;
                }
                let same = open == around;
                let plane = &mut self.list[j];
                if same {
                    (plane.best, plane.bound, plane.state, plane.sweep) = (rect, best, Bound::Exact, None);
                } else if plane.state != Bound::Exact {
                    plane.bound = plane.bound.min(best);
                }
            }
        }
    }
}

/// An upper bound on the cells of the largest open rectangle. It spans at least two rows
/// (`MIN_SIDE`), and each two rows of it next to each other have a run of cells open in both
/// as long as its width: so it fits under the histogram of those runs, one a pair of rows,
/// whose largest rectangle the stack method finds (a rectangle over k pairs spans k + 1
/// rows). Much tighter than a count of the cells once a taken rectangle has cut them apart,
/// at a fraction of a search's cost. `pair_runs` are the runs ([`PlaneCells::pair_runs`]),
/// read again from `open` over the pairs `stale`, as only those changed.
fn runs_bound(
    open: &[u64],
    row_words: usize,
    (pair_runs, stale): (&mut [usize], std::ops::Range<usize>),
    stack: &mut Vec<(usize, usize)>,
) -> usize {
    const _: () = assert!(MIN_SIDE >= 2, "a rectangle spans a pair of rows");
    let rows = pair_runs.len();
    for u in stale.start..stale.end.min(rows.saturating_sub(1)) {
        let (upper, lower) = (&open[u * row_words..], &open[(u + 1) * row_words..]);
        pair_runs[u] = longest_run(upper[..row_words].iter().zip(lower).map(|(a, b)| a & b));
    }
    stack.clear();
    let mut best = 0;
    // The one past the last pair, 0, ends every rectangle.
    for (u, &run) in pair_runs.iter().enumerate() {
        // Where a rectangle as wide as this pair's run begins: the first pair of those it ends.
        let mut start = u;
        while let Some(&(first, width)) = stack.last() {
            if width <= run {
                break;
            }
            stack.pop();
            best = best.max(width * (u - first + 1));
            start = first;
        }
        if run > 0 && stack.last().is_none_or(|&(_, width)| width < run) {
            stack.push((start, run));
        }
    }
    best
}

/// The most set bits side by side in a row's words.
fn longest_run(words: impl Iterator<Item = u64>) -> usize {
    let (mut longest, mut current) = (0, 0);
    for word in words {
        match word {
            0 => current = 0,
            u64::MAX => current += 64,
            _ => {
                // The run from the words before ends in this word's lowest bits.
                longest = longest.max(current + word.trailing_ones() as usize);
                let mut rest = word;
                while rest != 0 {
                    rest >>= rest.trailing_zeros();
                    let ones = rest.trailing_ones();
                    longest = longest.max(ones as usize);
                    rest = rest.checked_shr(ones).unwrap_or(0);
                }
                current = word.leading_ones() as usize;
            }
        }
        longest = longest.max(current);
    }
    longest
}

/// Widens `range` to hold `by` too, or sets it to `by` where it is None.
fn widen(range: &mut Option<std::ops::Range<usize>>, by: std::ops::Range<usize>) {
    *range = Some(
        range
            .take()
            .map_or(by.clone(), |r| r.start.min(by.start)..r.end.max(by.end)),
    );
}

/// The bits, of a word of a row whose first column is `first`, of the columns before `v`.
fn columns_before(first: usize, v: usize) -> u64 {
    match v.saturating_sub(first) {
        0 => 0,
        k if k >= 64 => u64::MAX,
        k => (1u64 << k) - 1,
    }
}

/// The first and last rows and columns with an open cell, if any.
fn open_bounds(open: &[u64], row_words: usize) -> Option<([usize; 2], [usize; 2])> {
    // Each row's first and last open column, where it has any.
    let mut rows = open.chunks(row_words).enumerate().filter_map(|(u, row)| {
        let (a, b) = (row.iter().position(|&w| w != 0)?, row.iter().rposition(|&w| w != 0)?);
        let first = a * 64 + row[a].trailing_zeros() as usize;
        Some((u, first, b * 64 + 63 - row[b].leading_zeros() as usize))
    });
    let (u0, mut v0, mut v1) = rows.next()?;
    let mut u1 = u0;
    for (u, first, last) in rows {
        (u1, v0, v1) = (u, v0.min(first), v1.max(last));
    }
    Some(([u0, v0], [u1, v1]))
}

/// Greedy: the largest open rectangle over all candidate planes, then the next on what is left.
/// A plane is searched only once an upper bound on its rectangle leads all others: its open
/// cells at first, or after a taken rectangle closes a cell of its best, the fewer of that
/// best's and its open cells; when such a bound leads, it is first cut to what the runs of
/// cells open in its pairs of rows allow ([`runs_bound`]), and the plane searched if it still
/// leads. A plane with the same open cells as a neighbour searched since takes its best. These
/// are lazy greedy picks, the same as searching every plane at first and again whenever it
/// loses cells.
fn best_rectangles(g: &AxisGrid, gaps: &Gaps, planes: (&[f64], PlaneOrder), margin: f64, inset: f64) -> Vec<Panel> {
    let nv = g.dims[1];
    let mut planes = Planes::new(gaps, planes, g.dims);
    let mut quads = Vec::new();
    let mut filled = Vec::new();
    let mut stack = Vec::new();
    while quads.len() < MAX_PER_AXIS {
        let candidates = &planes.list;
        let Some(top) = (0..candidates.len())
            .filter(|&i| candidates[i].bound >= MIN_CELLS)
            .max_by(|&a, &b| {
                let (a, b) = (&candidates[a], &candidates[b]);
                a.bound.cmp(&b.bound).then(b.t.total_cmp(&a.t))
            })
        else {
            break;
        };
        match candidates[top].state {
            Bound::Counted => {
                let plane = &mut planes.list[top];
                let stale = plane.stale_pairs.take().unwrap_or(0..0);
                let runs = runs_bound(&plane.open, planes.row_words, (&mut plane.pair_runs, stale), &mut stack);
                plane.bound = plane.bound.min(runs);
                plane.state = Bound::Runs;
                continue;
            }
            Bound::Runs => {
                planes.search(top);
                continue;
            }
            Bound::Exact => {}
        }
        let (rect, plane) = (
            planes.list[top].best.expect("an exact bound counts its best"),
            planes.list[top].t,
        );
        // Centre the quad in the heights that every cell of the rectangle leaves open.
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        filled.clear();
        for (u, v) in rect.iter() {
            let c = u * nv + v;
            let k = gaps.starts[c]
                + gaps
                    .of(c)
                    .iter()
                    .position(|gap| gap.holds(plane, margin))
                    .expect("the rectangle's cells hold the plane");
            lo = lo.max(gaps.list[k].lo);
            hi = hi.min(gaps.list[k].hi);
            filled.push(k);
        }
        planes.close(&rect, &filled);
        let t = 0.5 * (lo + hi);
        // Inset from the cells' edges, where the surface may lie just beyond, by what writing
        // the corners as f32 may move them.
        let u = [g.line(0, rect.u[0]) + inset, g.line(0, rect.u[1]) - inset];
        let v = [g.line(1, rect.v[0]) + inset, g.line(1, rect.v[1]) - inset];
        if u[0] >= u[1] || v[0] >= v[1] {
            continue;
        }
        let corners = [(u[0], v[0]), (u[1], v[0]), (u[1], v[1]), (u[0], v[1])];
        quads.push(Panel {
            shape: Shape::Quads,
            corners: corners.map(|(a, b)| g.point(a, b, t).to_array()),
        });
    }
    quads
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluder::WorldBox;
    use crate::occluder::rectangle::{bit_rows, largest};
    use crate::voxel::columns::column_hit;

    /// A box with a hollow, and a turned box through the shell and the hollow: winding numbers
    /// 0, 1 and 2, where parity and winding disagree.
    fn hollow_box() -> Mesh {
        let mut mesh = Mesh::default();
        let mut add = |lo: [f64; 3], hi: [f64; 3], turn: DQuat, inward: bool| {
            for tri in (WorldBox { lo, hi }).triangles() {
                let tri = tri.map(|p| (turn * p).as_vec3());
                let base = mesh.positions.len() as u32;
                mesh.positions
                    .extend(if inward { [tri[0], tri[2], tri[1]] } else { tri });
                mesh.triangles.push([base, base + 1, base + 2]);
            }
        };
        add([0.0; 3], [4.0; 3], DQuat::IDENTITY, false);
        add([1.0; 3], [3.0; 3], DQuat::IDENTITY, true);
        add(
            [1.5, 0.5, -0.5],
            [2.5, 1.5, 3.5],
            DQuat::from_euler(glam::EulerRot::XYZ, 0.3, 0.5, 0.2),
            false,
        );
        mesh
    }

    /// Whether `p` is inside `mesh` by the crossings of the line up from it: the winding
    /// number at least 1, or with `parity`, the count odd.
    fn inside_by_crossings(mesh: &Mesh, p: DVec3, parity: bool) -> bool {
        let hits = (0..mesh.triangles.len()).filter_map(|t| {
            column_hit(&mesh.corners(t).map(|c| c.as_dvec3().to_array()), [p.x, p.y]).filter(|hit| hit.z > p.z)
        });
        let (sum, count) = hits.fold((0, 0), |(sum, count), hit| (sum + i32::from(hit.sign), count + 1));
        if parity { count % 2 == 1 } else { sum >= 1 }
    }

    /// A box around all of [`hollow_box`].
    const EVERYWHERE: [WorldBox; 1] = [WorldBox {
        lo: [-1.0; 3],
        hi: [5.0; 3],
    }];

    #[test]
    fn a_closed_surfaces_crossings_decide_its_gaps_as_point_queries_do() {
        let mesh = hollow_box();
        for parity in [false, true] {
            let inside = |p: DVec3| inside_by_crossings(&mesh, p, parity);
            let within = &EVERYWHERE;
            let by_points = find(&mesh, 40, Solid::Points { at: &inside, within });
            assert!(by_points.len() > 12, "{} quads", by_points.len());
            assert_eq!(find(&mesh, 40, Solid::Closed { parity }), by_points, "parity {parity}");
        }
    }

    #[test]
    fn cells_whose_centre_lines_miss_the_boxes_a_solid_lies_in_are_left_out_exactly() {
        let mesh = hollow_box();
        // Boxes that cut across cells and the turned frames' diagonals.
        let within = [
            WorldBox {
                lo: [0.23, 0.31, 0.17],
                hi: [1.37, 3.71, 2.03],
            },
            WorldBox {
                lo: [2.61, 0.47, 0.29],
                hi: [3.58, 1.93, 3.77],
            },
        ];
        let in_a_box = |p: DVec3| within.iter().any(|b| p.cmpge(b.lo()).all() && p.cmple(b.hi()).all());
        let inside = |p: DVec3| in_a_box(p) && inside_by_crossings(&mesh, p, false);
        let left_out = find(
            &mesh,
            40,
            Solid::Points {
                at: &inside,
                within: &within,
            },
        );
        assert!(left_out.len() > 12, "{} quads", left_out.len());
        let everywhere = find(
            &mesh,
            40,
            Solid::Points {
                at: &inside,
                within: &EVERYWHERE,
            },
        );
        assert_eq!(left_out, everywhere);
    }

    #[test]
    fn gaps_of_cells_side_by_side_that_overlap_are_decided_once_a_region() {
        let margin = 0.01;
        // 3 × 4 cells, the second axis fastest: a low gap in each, and a high one in each but
        // cell 5, which the others reach round it; cells 10 and 11 have higher ones instead,
        // which overlap by the margin alone.
        let mut gaps = Gaps {
            starts: vec![0],
            list: Vec::new(),
        };
        for c in 0..12 {
            let shift = c as f64 * 0.05;
            gaps.list.push(Gap {
                lo: shift,
                hi: 2.0 + shift,
            });
            match c {
                5 => {}
                10 => gaps.list.push(Gap { lo: 5.0, hi: 6.0 }),
                11 => gaps.list.push(Gap { lo: 5.99, hi: 7.0 }),
                _ => gaps.list.push(Gap { lo: 3.0, hi: 4.0 }),
            }
            gaps.starts.push(gaps.list.len());
        }
        let asked = std::cell::RefCell::new(Vec::new());
        let inside = inside_by_regions(&gaps, 4, margin, |c, gap| {
            asked.borrow_mut().push((c, gap));
            gaps.list[gap].lo >= 3.0
        });
        // The low gaps, the high ones of cells 0-4 and 6-9, cell 10's and cell 11's.
        assert_eq!(asked.into_inner(), [(0, 0), (0, 1), (10, 20), (11, 22)]);
        assert_eq!(inside, gaps.list.iter().map(|gap| gap.lo >= 3.0).collect::<Vec<_>>());
    }

    /// The part of a convex polygon with coordinate `k` on one side of `bound`, closed
    /// (Sutherland–Hodgman).
    fn clip_side(polygon: &[[f64; 3]], k: usize, bound: f64, above: bool) -> Vec<[f64; 3]> {
        let keeps = |p: &[f64; 3]| if above { p[k] >= bound } else { p[k] <= bound };
        let mut out = Vec::new();
        for (i, a) in polygon.iter().enumerate() {
            let b = &polygon[(i + 1) % polygon.len()];
            if keeps(a) {
                out.push(*a);
            }
            if keeps(a) != keeps(b) {
                let s = (bound - a[k]) / (b[k] - a[k]);
                out.push(std::array::from_fn(|j| {
                    if j == k { bound } else { a[j] + s * (b[j] - a[j]) }
                }));
            }
        }
        out
    }

    #[test]
    fn cell_heights_are_those_of_the_triangle_clipped_to_each_cell() {
        let mut rng = fastrand::Rng::with_seed(3);
        let mut cells = CellHeights::default();
        let g = AxisGrid {
            turn: DQuat::IDENTITY,
            axis: 2,
            origin: [0.0, 0.0],
            cell: 0.5,
            dims: [7, 7],
        };
        for round in 0..4000 {
            // Corners on the lines now and then, as a mesh on the grid has them, and walls
            // standing on the grid now and then.
            let coordinate = |rng: &mut fastrand::Rng| match rng.usize(0..4) {
                0 => rng.usize(0..8) as f64 * 0.5,
                _ => rng.f64() * 3.5,
            };
            let mut tri: [[f64; 3]; 3] =
                std::array::from_fn(|_| [coordinate(&mut rng), coordinate(&mut rng), rng.f64() * 10.0 - 5.0]);
            if round % 10 == 0 {
                let k = rng.usize(0..2);
                let wall = coordinate(&mut rng);
                tri.iter_mut().for_each(|p| p[k] = wall);
            }
            let places = tri.map(|p| g.place_of(&p));
            let (ru, rv) = (g.range_of(0, &places), g.range_of(1, &places));
            cells.of_triangle(&tri, &places, &g, [ru.start, rv.start], [ru.len(), rv.len()]);
            let width = rv.len() + 2;
            let each = ru.clone().flat_map(|u| rv.clone().map(move |v| (u, v)));
            for (u, v) in each {
                let (t0, t1) = cells.heights[(u + 1 - ru.start) * width + v + 1 - rv.start];
                let mut part = tri.to_vec();
                for (k, index) in [(0, u), (1, v)] {
                    part = clip_side(&part, k, g.line(k, index), true);
                    part = clip_side(&part, k, g.line(k, index + 1), false);
                }
                let ts = part.iter().map(|p| p[2]);
                let (c0, c1) = (
                    ts.clone().fold(f64::INFINITY, f64::min),
                    ts.fold(f64::NEG_INFINITY, f64::max),
                );
                if part.is_empty() {
                    assert!(t0 > t1, "{tri:?} cell {u} {v}: ({t0}, {t1}) where the clip is empty");
                } else {
                    assert!(
                        (c0 - t0).abs() < 1e-9 && (c1 - t1).abs() < 1e-9,
                        "{tri:?} cell {u} {v}: ({t0}, {t1}) against ({c0}, {c1})"
                    );
                }
            }
        }
    }

    #[test]
    fn the_lazy_greedy_takes_what_searching_every_plane_each_time_takes() {
        let mut rng = fastrand::Rng::with_seed(17);
        let mut taken = 0;
        for _ in 0..20 {
            let dims = [rng.usize(10..30), rng.usize(20..90)];
            let (nu, nv) = (dims[0], dims[1]);
            let g = AxisGrid {
                turn: DQuat::IDENTITY,
                axis: 2,
                origin: [0.0, 0.0],
                cell: 1.0,
                dims,
            };
            // Smooth walls with a round hole and a few single ones, and now and then a second
            // gap above.
            let mut gaps = Gaps {
                starts: vec![0],
                list: Vec::new(),
            };
            let (a, b) = (rng.f64() * 6.0 + 2.0, rng.f64() * 6.0 + 2.0);
            let hole = [rng.f64() * nu as f64, rng.f64() * nv as f64, rng.f64() * 5.0];
            for c in 0..nu * nv {
                let (u, v) = ((c / nv) as f64, (c % nv) as f64);
                let lo = 2.0 + (u / a).sin() + (v / b).cos();
                let in_hole = (u - hole[0]).hypot(v - hole[1]) < hole[2];
                if !in_hole && rng.f64() < 0.99 {
                    gaps.list.push(Gap {
                        lo,
                        hi: lo + 3.0 + (v / a).sin() * 2.0,
                    });
                }
                if rng.f64() < 0.3 {
                    gaps.list.push(Gap { lo: 9.0, hi: 9.5 });
                }
                gaps.starts.push(gaps.list.len());
            }
            let planes: Vec<f64> = (0..40).map(|_| rng.f64() * 10.0).collect();
            let margin = 1e-6;
            let order = PlaneOrder::new(&gaps, &planes, margin);
            let lazy: Vec<[f64; 2]> = best_rectangles(&g, &gaps, (&planes, order), margin, 0.0)
                .iter()
                .flat_map(|q| [[q.corners[0][0], q.corners[0][1]], [q.corners[2][0], q.corners[2][1]]])
                .collect();
            let mut open: Vec<Vec<bool>> = planes
                .iter()
                .map(|&t| {
                    (0..nu * nv)
                        .map(|c| gaps.of(c).iter().any(|gap| gap.holds(t, margin)))
                        .collect()
                })
                .collect();
            let mut eager = Vec::new();
            while eager.len() < 2 * MAX_PER_AXIS {
                let found = (0..planes.len()).filter_map(|i| {
                    let rect = largest(&open[i], nu, nv, MIN_SIDE).filter(|r| r.cells() >= MIN_CELLS)?;
                    Some((rect, planes[i]))
                });
                let Some((rect, t)) = found.max_by(|a, b| a.0.cells().cmp(&b.0.cells()).then(b.1.total_cmp(&a.1)))
                else {
                    break;
                };
                eager.extend([[rect.u[0], rect.v[0]], [rect.u[1], rect.v[1]]].map(|c| c.map(|k| k as f64)));
                for (u, v) in rect.iter() {
                    let c = u * nv + v;
                    let gap = gaps.of(c).iter().find(|gap| gap.holds(t, margin)).expect("open");
                    for (open, &t) in open.iter_mut().zip(&planes) {
                        if gap.holds(t, margin) {
                            open[c] = false;
                        }
                    }
                }
            }
            assert_eq!(lazy, eager);
            taken += eager.len() / 2;
        }
        assert!(taken > 200, "{taken} quads");
    }

    #[test]
    fn the_runs_open_in_pairs_of_rows_bound_the_largest_rectangle_meet_it_on_one_and_keep_as_cells_close() {
        let mut rng = fastrand::Rng::with_seed(5);
        let mut stack = Vec::new();
        for round in 0..400 {
            let (nu, nv) = (rng.usize(1..12), rng.usize(1..200));
            let row_words = nv.div_ceil(64);
            // Some masks nearly full, so that runs cross whole words.
            let fill = if round % 2 == 0 { 0.8 } else { 0.995 };
            let mask: Vec<bool> = (0..nu * nv).map(|_| rng.f64() < fill).collect();
            let bits = bit_rows(&mask, nu, nv);
            for u in 0..nu {
                let row = &mask[u * nv..(u + 1) * nv];
                let longest = row.split(|open| !open).map(<[bool]>::len).max().unwrap_or(0);
                assert_eq!(
                    longest_run(bits[u * row_words..(u + 1) * row_words].iter().copied()),
                    longest
                );
            }
            let largest_cells = largest(&mask, nu, nv, MIN_SIDE).map_or(0, |r| r.cells());
            let bound =
                |bits: &[u64], stack: &mut Vec<_>| runs_bound(bits, row_words, (&mut vec![0; nu], 0..nu), stack);
            assert!(bound(&bits, &mut stack) >= largest_cells);
            // Cells closed in one row: the runs read again over the pairs holding that row
            // alone are those read afresh, and so is the bound.
            let mut runs = vec![0; nu];
            runs_bound(&bits, row_words, (&mut runs, 0..nu), &mut stack);
            let mut closed = bits.clone();
            let u = rng.usize(0..nu);
            closed[u * row_words..(u + 1) * row_words]
                .iter_mut()
                .for_each(|w| *w &= rng.u64(..));
            let again = runs_bound(&closed, row_words, (&mut runs, u.saturating_sub(1)..u + 1), &mut stack);
            let mut fresh = vec![0; nu];
            assert_eq!(again, runs_bound(&closed, row_words, (&mut fresh, 0..nu), &mut stack));
            assert_eq!(runs, fresh);
            // One rectangle alone, at least two rows high: the bound is its cells.
            if nu < MIN_SIDE {
                continue;
            }
            let (u0, v0) = (rng.usize(0..nu - 1), rng.usize(0..nv));
            let rect = CellRect {
                u: [u0, rng.usize(u0 + 2..=nu)],
                v: [v0, rng.usize(v0 + 1..=nv)],
            };
            let mut one = vec![false; nu * nv];
            for (u, v) in rect.iter() {
                one[u * nv + v] = true;
            }
            assert_eq!(bound(&bit_rows(&one, nu, nv), &mut stack), rect.cells());
        }
    }
}
