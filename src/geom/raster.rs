//! Software rasterization at pixel centres: depth images of meshes and coverage masks of boxes,
//! through orthographic cameras around a mesh or perspective cameras inside it. The depth
//! images have a GPU twin, [`gpu`] (shaders/raster.wgsl).

pub mod covered;
pub mod gpu;

use crate::geom::camera::{Lens, View};
use crate::geom::{ceil_index, clamped_index, floor_index, greater, index_to_f64, lesser, with_avx2};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;

/// Calls `visit(pixel index, depth)` for every pixel centre the projected triangle covers.
/// Edges are inclusive, so triangles sharing an edge leave no crack.
pub fn rasterize(view: &View, tri: &[DVec3; 3], visit: impl FnMut(usize, f64)) {
    rasterize_with(view, tri, Coverage::Centres, Span::all(view), visit);
}

/// Like [`rasterize`], but only the pixels in columns `xs` and rows `ys`.
pub fn rasterize_within(
    view: &View,
    tri: &[DVec3; 3],
    xs: std::ops::RangeInclusive<usize>,
    ys: std::ops::RangeInclusive<usize>,
    visit: impl FnMut(usize, f64),
) {
    let within = Span {
        x: (*xs.start(), *xs.end()),
        y: (*ys.start(), *ys.end()),
    };
    rasterize_with(view, tri, Coverage::Centres, within, visit);
}

/// Like [`rasterize`], but only pixels the triangle covers whole, each with the farthest depth
/// over the pixel: what an occluder certainly hides at this resolution.
pub fn rasterize_inner(view: &View, tri: &[DVec3; 3], visit: impl FnMut(usize, f64)) {
    rasterize_with(view, tri, Coverage::Whole, Span::all(view), visit);
}

#[derive(Clone, Copy, PartialEq)]
enum Coverage {
    /// Pixels whose centre the triangle covers, at the centre's depth.
    Centres,
    /// Pixels wholly inside the triangle, at the farthest depth of their corners.
    Whole,
    /// Pixel centres the triangle covers, whose squares also lie wholly inside the flagged edges.
    Eroded([bool; 3]),
}

fn rasterize_with(view: &View, tri: &[DVec3; 3], coverage: Coverage, within: Span, visit: impl FnMut(usize, f64)) {
    let mut pixels = EachPixel(visit);
    let q = tri.map(|v| view.project(v));
    match view.lens {
        Lens::Orthographic { .. } => fill(view, q, coverage, |d| d, within, &mut pixels),
        Lens::Perspective { .. } => fill_perspective(view, tri, q, coverage, within, &mut pixels),
    }
}

/// Where a fill's pixels go: one by one with their depths, or, for a sink that reads no
/// depths, as whole runs along a row.
trait Pixels {
    /// Whether it takes runs, without depths: every run's end is then searched for.
    const RUNS: bool;
    fn pixel(&mut self, index: usize, depth: f64);
    /// [`Pixels::pixel`] where `drawn`, for a pixel tested alone: a sink that can take it
    /// without a branch (which no predictor guesses well on small triangles) does.
    #[inline(always)]
    fn pixel_where(&mut self, drawn: bool, index: usize, depth: impl FnOnce() -> f64) {
        if drawn {
            self.pixel(index, depth());
        }
    }
    /// Pixels `xs` of the row that starts at pixel index `row`.
    fn run(&mut self, row: usize, xs: std::ops::RangeInclusive<usize>);
    /// For a sink that keeps each pixel's nearest depth, its image, into which an orthographic
    /// view's triangles with no edge flagged are drawn a few pixels at a time
    /// ([`Rows::fill_nearest`]).
    #[inline(always)]
    fn nearest(&mut self) -> Option<&mut [f32]> {
        None
    }
}

/// Each pixel's nearest depth, into an image.
struct Nearest<'a>(&'a mut [f32]);

impl Pixels for Nearest<'_> {
    const RUNS: bool = false;

    #[inline(always)]
    fn pixel(&mut self, index: usize, depth: f64) {
        self.0[index] = self.0[index].min(depth as f32);
    }

    fn run(&mut self, _: usize, _: std::ops::RangeInclusive<usize>) {
        unreachable!("pixels with depths are visited one by one")
    }

    #[inline(always)]
    fn nearest(&mut self) -> Option<&mut [f32]> {
        Some(self.0)
    }
}

/// Each pixel with its depth, to `visit(pixel index, depth)`.
struct EachPixel<F>(F);

impl<F: FnMut(usize, f64)> Pixels for EachPixel<F> {
    const RUNS: bool = false;

    #[inline(always)]
    fn pixel(&mut self, index: usize, depth: f64) {
        (self.0)(index, depth);
    }

    fn run(&mut self, _: usize, _: std::ops::RangeInclusive<usize>) {
        unreachable!("pixels with depths are visited one by one")
    }
}

/// Coverage bits, one a pixel, set a word at a time; depths are never asked for.
struct Bits<'a> {
    mask: &'a mut [u64],
    /// The words set, from the first to one past the last.
    first: usize,
    end: usize,
}

impl Bits<'_> {
    fn new(mask: &mut [u64]) -> Bits<'_> {
        Bits {
            mask,
            first: usize::MAX,
            end: 0,
        }
    }
}

impl Pixels for Bits<'_> {
    const RUNS: bool = true;

    fn pixel(&mut self, index: usize, _: f64) {
        self.run(index, 0..=0);
    }

    #[inline(always)]
    fn pixel_where(&mut self, drawn: bool, index: usize, _: impl FnOnce() -> f64) {
        let word = index / 64;
        self.mask[word] |= u64::from(drawn) << (index % 64);
        let (first, end) = (self.first.min(word), self.end.max(word + 1));
        (self.first, self.end) = if drawn { (first, end) } else { (self.first, self.end) };
    }

    fn run(&mut self, row: usize, xs: std::ops::RangeInclusive<usize>) {
        let (a, b) = (row + xs.start(), row + xs.end());
        let (wa, wb) = (a / 64, b / 64);
        let from = u64::MAX << (a % 64);
        let to = u64::MAX >> (63 - b % 64);
        if wa == wb {
            self.mask[wa] |= from & to;
        } else {
            self.mask[wa] |= from;
            self.mask[wa + 1..wb].fill(u64::MAX);
            self.mask[wb] |= to;
        }
        (self.first, self.end) = (self.first.min(wa), self.end.max(wb + 1));
    }
}

/// A triangle of a perspective view, `tri` in the world and `q` its corners as
/// [`View::project`] gives them, clipped to the near plane in front of the eye: 1/z is what
/// varies linearly on screen.
fn fill_perspective(
    view: &View,
    tri: &[DVec3; 3],
    q: [DVec3; 3],
    coverage: Coverage,
    within: Span,
    visit: &mut impl Pixels,
) {
    let near = view.depth_tolerance();
    // A triangle clipped by one plane has at most four corners.
    let (mut poly, mut corners) = ([DVec3::ZERO; 4], 0);
    for k in 0..3 {
        let (a, b) = (k, (k + 1) % 3);
        if q[a].z >= near {
            poly[corners] = q[a];
            corners += 1;
        }
        if (q[a].z >= near) != (q[b].z >= near) {
            let s = (near - q[a].z) / (q[b].z - q[a].z);
            poly[corners] = view.project(tri[a] + (tri[b] - tri[a]) * s);
            corners += 1;
        }
    }
    for k in 1..corners.saturating_sub(1) {
        fill(
            view,
            [poly[0], poly[k], poly[k + 1]],
            coverage,
            |d| 1.0 / d,
            within,
            visit,
        );
    }
}

/// Visits the pixels of the screen triangle `p` (x, y, depth) by `coverage`, interpolating
/// `along(depth)` across the screen: the depth itself (orthographic), or its reciprocal
/// (perspective), which is what varies linearly there. Either is its own inverse, and turns an
/// interpolated value back into a depth. Only pixels `within` are visited.
fn fill(
    view: &View,
    p: [DVec3; 3],
    coverage: Coverage,
    along: impl Fn(f64) -> f64,
    within: Span,
    visit: &mut impl Pixels,
) {
    let q = p.map(|v| v.truncate());
    let lo = q[0].min(q[1]).min(q[2]);
    let hi = q[0].max(q[1]).max(q[2]);
    // The pixels i whose sample points (the centre i + 0.5, or the whole [i, i + 1]) lie in
    // [lo, hi]. Most triangles of a detailed mesh cover none, so this comes first, without
    // rounding calls.
    let (inset, reach) = match coverage {
        Coverage::Centres | Coverage::Eroded(_) => (0.5, 0.5),
        Coverage::Whole => (0.0, 1.0),
    };
    let pixels = |lo: f64, hi: f64, (first, last): (usize, usize)| -> Option<(usize, usize)> {
        let (a, b) = (
            (lo - inset).max(index_to_f64(first)),
            (hi - reach).min(index_to_f64(last)),
        );
        // Also rejects NaN.
        if a.partial_cmp(&b).is_none_or(|o| o.is_gt()) {
            return None;
        }
        let (first, last) = (ceil_index(a), floor_index(b));
        (first <= last).then_some((first, last))
    };
    let (Some(x), Some(y)) = (pixels(lo.x, hi.x, within.x), pixels(lo.y, hi.y, within.y)) else {
        return;
    };
    fill_span(view, p, coverage, along, Span { x, y }, visit);
}

/// [`fill`] once the pixels that the triangle's samples may cover, `span`, are found.
#[inline(always)]
fn fill_span(
    view: &View,
    p: [DVec3; 3],
    coverage: Coverage,
    along: impl Fn(f64) -> f64,
    span: Span,
    visit: &mut impl Pixels,
) {
    let q = p.map(|v| v.truncate());
    let area = cross(q[1] - q[0], q[2] - q[0]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    // Only for a triangle with pixels to draw: a perspective view's reciprocals divide.
    let p = p.map(|v| DVec3::new(v.x, v.y, along(v.z)));
    match coverage {
        Coverage::Whole => fill_whole(view, p, area, span, along, visit),
        Coverage::Centres => fill_centres(view, p, area, [false; 3], span, along, visit),
        Coverage::Eroded(eroded) => fill_centres(view, p, area, eroded, span, along, visit),
    }
}

/// The first and last pixel along x and along y that a triangle's samples may cover.
#[derive(Clone, Copy)]
struct Span {
    x: (usize, usize),
    y: (usize, usize),
}

impl Span {
    /// Every pixel of the view.
    fn all(view: &View) -> Span {
        let last = view.pixels - 1;
        Span {
            x: (0, last),
            y: (0, last),
        }
    }
}

/// The value of `p`'s third coordinate at barycentric weights `w`.
fn interpolate(p: &[DVec3; 3], w: [f64; 3]) -> f64 {
    w[0] * p[0].z + w[1] * p[1].z + w[2] * p[2].z
}

/// [`Coverage::Whole`]: the pixels whose four corners the triangle covers, at the farthest
/// depth of the corners.
fn fill_whole(view: &View, p: [DVec3; 3], area: f64, span: Span, depth: impl Fn(f64) -> f64, visit: &mut impl Pixels) {
    let q = p.map(|v| v.truncate());
    let weights = |c: DVec2| {
        [
            cross(q[2] - q[1], c - q[1]) / area,
            cross(q[0] - q[2], c - q[2]) / area,
            cross(q[1] - q[0], c - q[0]) / area,
        ]
    };
    for y in span.y.0..=span.y.1 {
        for x in span.x.0..=span.x.1 {
            let (x_f, y_f) = (index_to_f64(x), index_to_f64(y));
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                .map(|(dx, dy)| weights(DVec2::new(x_f + dx, y_f + dy)));
            if corners.iter().flatten().all(|&v| v >= 0.0) {
                let farthest = corners
                    .iter()
                    .map(|&w| depth(interpolate(&p, w)))
                    .fold(f64::NEG_INFINITY, f64::max);
                visit.pixel(y * view.pixels + x, farthest);
            }
        }
    }
}

/// [`Coverage::Centres`] and [`Coverage::Eroded`]: the pixels whose centres the triangle
/// covers, and whose squares lie wholly inside the edges flagged in `eroded`.
#[inline(always)]
fn fill_centres<V: Pixels>(
    view: &View,
    p: [DVec3; 3],
    area: f64,
    eroded: [bool; 3],
    span: Span,
    depth: impl Fn(f64) -> f64,
    visit: &mut V,
) {
    let q = p.map(|v| v.truncate());
    // Edge k's function f at a centre c is `cross(q[k + 2] - q[k + 1], c - q[k + 1])`, computed
    // in the same operations as `fill_whole`'s weights, so that the pixels and depths are those
    // of the pixel-by-pixel test to the bit. Its weight f / area is at least 0 exactly where f
    // has the area's sign, so only the pixels drawn pay for the divisions. The edges of a
    // clockwise triangle are negated, and its area with them: negation is exact, so every
    // function is negated to the bit and holds where it is at least 0, and the weights stay.
    let sign = area.signum();
    let edges = [(q[2] - q[1], q[1]), (q[0] - q[2], q[2]), (q[1] - q[0], q[0])].map(|(e, o)| (e * sign, o));
    let area = area.abs();
    let rows = Rows { edges, area, span };
    if eroded == [false; 3] {
        let orthographic = matches!(view.lens, Lens::Orthographic { .. });
        match visit.nearest() {
            Some(image) if orthographic && view.pixels >= LANES => rows.fill_nearest(&p, view.pixels, image),
            _ => rows.fill(view, &p, |_, f| f >= 0.0, depth, visit),
        }
        return;
    }
    // How far inside each edge a pixel centre must be, as a weight, for the pixel's square to be:
    // across the square, the edge's function changes by half the sum of its |dx| and |dy|.
    let insets: [f64; 3] = std::array::from_fn(|k| {
        let edge = edges[k].0;
        if eroded[k] {
            0.5 * (edge.x.abs() + edge.y.abs()) / area
        } else {
            0.0
        }
    });
    let holds = |k: usize, f: f64| match insets[k] {
        0.0 => f >= 0.0,
        inset => f / area >= inset,
    };
    rows.fill(view, &p, holds, depth, visit);
}

/// A triangle's edges as [`fill_centres`] turns them, each with a corner on it, its area, and
/// the pixels its samples may cover.
struct Rows {
    edges: [(DVec2, DVec2); 3],
    area: f64,
    span: Span,
}

impl Rows {
    /// Visits the pixels whose centres pass `holds` (edge k, its function there) for every edge,
    /// at `depth` of the corners' values weighed there.
    #[inline(always)]
    fn fill<V: Pixels>(
        &self,
        view: &View,
        p: &[DVec3; 3],
        holds: impl Fn(usize, f64) -> bool,
        depth: impl Fn(f64) -> f64,
        visit: &mut V,
    ) {
        let Rows { edges, area, span } = *self;
        // Depths weigh the corners by edge function times this, not over the area: three
        // multiplications a pixel instead of three divisions.
        let per_area = 1.0 / area;
        let depth_at = |f: [f64; 3]| depth(interpolate(p, f.map(|f| f * per_area)));
        let in_row = |row: [f64; 3]| move |k: usize, x: usize| self.at(&row, k, x);
        let (x0, x1) = span.x;
        let (y0, y1) = span.y;
        if x1 - x0 <= 1 && y1 - y0 <= 1 {
            // At most 2 × 2 pixels, as for most triangles of a detailed mesh: all four tested
            // the same way, those past the span drawn nowhere, so that nothing branches on the
            // size.
            for dy in 0..2 {
                let y = (y0 + dy).min(y1);
                let function = in_row(self.row(y));
                for dx in 0..2 {
                    let x = (x0 + dx).min(x1);
                    let f: [f64; 3] = std::array::from_fn(|k| function(k, x));
                    let within = x0 + dx <= x1 && y0 + dy <= y1;
                    let drawn = within & holds(0, f[0]) & holds(1, f[1]) & holds(2, f[2]);
                    visit.pixel_where(drawn, y * view.pixels + x, || depth_at(f));
                }
            }
            return;
        }
        if !V::RUNS && (x1 - x0 + 1) * (y1 - y0 + 1) <= SMALL {
            // Few pixels: each tested alone, with the same operations.
            for y in span.y.0..=span.y.1 {
                let function = in_row(self.row(y));
                for x in x0..=x1 {
                    let f: [f64; 3] = std::array::from_fn(|k| function(k, x));
                    if holds(0, f[0]) & holds(1, f[1]) & holds(2, f[2]) {
                        visit.pixel(y * view.pixels + x, depth_at(f));
                    }
                }
            }
            return;
        }
        // Along a row each edge's function is monotone, rounding and all: an edge whose function
        // rises towards the triangle's side only starts to hold, the others only stop. Where the
        // edges cross the row leaves a few candidate pixels ([`row_span`]), none on most rows of
        // a sliver. Among them, the run of pixels drawn starts where the last rising edge holds,
        // searched for, and ends before the first other edge stops holding: searched for too for
        // a sink of runs or a long row, else found as the pixels are drawn (most runs of a
        // detailed mesh are a pixel or two long). Searches start at the candidates' ends
        // ([`first_where_near`]).
        let (rising, slopes) = self.crossings();
        for y in span.y.0..=span.y.1 {
            let row = self.row(y);
            let Some((lo, hi)) = row_span(&edges, row, rising, slopes, span.x) else {
                continue;
            };
            let function = in_row(row);
            let first = first_where_near(lo, hi + 1, lo, |x| {
                (0..3).all(|k| !rising[k] || holds(k, function(k, x)))
            });
            let ends_after = |x| (0..3).any(|k| !rising[k] && !holds(k, function(k, x)));
            if V::RUNS {
                let end = first_where_near(first, hi + 1, hi + 1, ends_after);
                if first < end {
                    visit.run(y * view.pixels, first..=end - 1);
                }
                continue;
            }
            let at = |x: usize| -> [f64; 3] { std::array::from_fn(|k| function(k, x)) };
            if hi + 1 - first >= LONG_ROW {
                // A long row's end is searched for too, and its pixels drawn without tests.
                for x in first..first_where_near(first, hi + 1, hi + 1, ends_after) {
                    visit.pixel(y * view.pixels + x, depth_at(at(x)));
                }
                continue;
            }
            for x in first..=hi {
                let f = at(x);
                if !(0..3).all(|k| holds(k, f[k])) {
                    break;
                }
                visit.pixel(y * view.pixels + x, depth_at(f));
            }
        }
    }

    /// The edges' functions at the centres of row y, less their terms in x ([`Rows::at`]).
    #[inline(always)]
    fn row(&self, y: usize) -> [f64; 3] {
        self.edges.map(|(e, o)| e.x * ((index_to_f64(y) + 0.5) - o.y))
    }

    /// Edge k's function at the centre of pixel x of the row whose [`Rows::row`] is `row`.
    #[inline(always)]
    fn at(&self, row: &[f64; 3], k: usize, x: usize) -> f64 {
        let (e, o) = self.edges[k];
        row[k] - e.y * ((index_to_f64(x) + 0.5) - o.x)
    }

    /// Per edge, whether its function rises towards the triangle's side along a row, and
    /// 1 / e.y, which [`row_span`] takes.
    #[inline(always)]
    fn crossings(&self) -> ([bool; 3], [f64; 3]) {
        (
            self.edges.map(|(e, _)| e.y * self.area < 0.0),
            self.edges.map(|(e, _)| 1.0 / e.y),
        )
    }

    /// [`Rows::fill`] with no edge flagged, of an orthographic view, into `depth`, an n × n image
    /// of nearest depths (n at least `LANES`): the same operations, so the same pixels and
    /// depths to the bit. A row's pixels are tested `LANES` at a time, all the same way, those
    /// outside the row's candidates left as they were: no branch on each pixel's test, which no
    /// predictor guesses well on small triangles.
    #[inline(always)]
    fn fill_nearest(&self, p: &[DVec3; 3], n: usize, depth: &mut [f32]) {
        let per_area = 1.0 / self.area;
        let (rising, slopes) = self.crossings();
        let (x0, x1) = self.span.x;
        for y in self.span.y.0..=self.span.y.1 {
            let row = self.row(y);
            // A narrow span is tested whole; a wide one only where the edges cross the row.
            let (lo, hi) = if x1 - x0 < 2 * LANES {
                (x0, x1)
            } else {
                match row_span(&self.edges, row, rising, slopes, self.span.x) {
                    Some(candidates) => candidates,
                    None => continue,
                }
            };
            let mut from = lo;
            while from <= hi {
                // At the end of the image's row, its last lanes: those before `lo` are left as
                // they are.
                let start = from.min(n - LANES);
                let pixels: &mut [f32; LANES] = (&mut depth[y * n + start..][..LANES]).try_into().unwrap();
                // `Rows::at` of each lane, the centres found once for the three edges.
                let centres: [f64; LANES] = std::array::from_fn(|l| index_to_f64(start + l) + 0.5);
                let f: [[f64; LANES]; 3] = std::array::from_fn(|k| {
                    let (e, o) = self.edges[k];
                    centres.map(|c| row[k] - e.y * (c - o.x))
                });
                for (l, pixel) in pixels.iter_mut().enumerate() {
                    let x = start + l;
                    let drawn = (x >= lo) & (x <= hi) & (f[0][l] >= 0.0) & (f[1][l] >= 0.0) & (f[2][l] >= 0.0);
                    let weighed = interpolate(p, [f[0][l] * per_area, f[1][l] * per_area, f[2][l] * per_area]);
                    let nearer = pixel.min(weighed as f32);
                    *pixel = if drawn { nearer } else { *pixel };
                }
                from = start + LANES;
            }
        }
    }
}

/// Pixels of a row that [`Rows::fill_nearest`] tests together, in a vector's lanes.
const LANES: usize = 4;

/// Candidate pixels up to which a triangle's are each tested alone.
const SMALL: usize = 4;

/// Pixels left in a row from which a depth image's run end is searched for.
const LONG_ROW: usize = 8;

/// The pixels of `x0..=x1` that a row can draw, or none: those that every edge's crossing of the
/// row, `o.x - 0.5 + row / e.y` with `slopes` 1 / e.y, leaves on its side. Rounding moves a
/// crossing, and the sign of the edge's function near it, by a few parts in 10¹⁶ of the numbers
/// involved; each crossing is widened by a millionth of a pixel and a millionth of a millionth of
/// them, so every pixel left out fails some edge's test, eroded or not (an eroded test holds only
/// where the plain one does). A crossing that is not a number bounds nothing.
fn row_span(
    edges: &[(DVec2, DVec2); 3],
    row: [f64; 3],
    rising: [bool; 3],
    slopes: [f64; 3],
    (x0, x1): (usize, usize),
) -> Option<(usize, usize)> {
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for (k, &rises) in rising.iter().enumerate() {
        let o = edges[k].1.x;
        let crossing = o - 0.5 + row[k] * slopes[k];
        let slack = 1e-6 + 1e-12 * (crossing.abs() + o.abs());
        if rises {
            lo = greater(lo, crossing - slack);
        } else {
            hi = lesser(hi, crossing + slack);
        }
    }
    if hi < 0.0 {
        return None;
    }
    let (first, last) = (ceil_index(lo).max(x0), floor_index(hi).min(x1));
    (first <= last).then_some((first, last))
}

/// [`first_where`], searched outwards from `guess`, the step doubling, then bisected: the same
/// answer for any guess, in a few tests when it is near.
fn first_where_near(from: usize, to: usize, guess: usize, test: impl Fn(usize) -> bool) -> usize {
    // Past `to` counts as holding, as `first_where` answers `to` where nothing holds.
    let holds = |x: usize| x >= to || test(x);
    let start = guess.min(to).max(from);
    let mut step = 1;
    if holds(start) {
        let mut held = start;
        loop {
            if held - from <= step {
                return first_where(from, held, &test);
            }
            let probe = held - step;
            if !holds(probe) {
                return first_where(probe + 1, held, &test);
            }
            held = probe;
            step *= 2;
        }
    }
    let mut failed = start;
    loop {
        let probe = failed + step;
        if probe >= to {
            return first_where(failed + 1, to, &test);
        }
        if holds(probe) {
            return first_where(failed + 1, probe, &test);
        }
        failed = probe;
        step *= 2;
    }
}

/// The first x in [from, to) where `test` holds, or `to`, for a test that once it holds, holds
/// on.
fn first_where(from: usize, to: usize, test: impl Fn(usize) -> bool) -> usize {
    let (mut first, mut end) = (from, to);
    while first < end {
        let mid = (first + end) / 2;
        if test(mid) {
            end = mid;
        } else {
            first = mid + 1;
        }
    }
    first
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Calls `visit(pixel index, depth)` for every pixel centre each triangle of `mesh` covers.
/// Each vertex is projected once.
pub fn rasterize_mesh(view: &View, mesh: &Mesh, visit: impl FnMut(usize, f64)) {
    fill_plain(view, mesh, &mut EachPixel(visit));
}

/// Draws `mesh` over `depth`, a depth image of `view`, where triangle t's edge k (from corner
/// k + 1 to corner k + 2) flagged in `eroded[t]` leaves out the pixels whose square it crosses:
/// where a crack narrower than a pixel runs along that edge, the pixel sees what lies behind.
pub fn draw_eroded(view: &View, mesh: &Mesh, eroded: &[[bool; 3]], depth: &mut [f32]) {
    fill_mesh(
        view,
        mesh,
        |t| eroded[t],
        &mut Nearest(depth),
        &mut DrawBuffers::default(),
    );
}

/// What drawing a mesh works out for each of its vertices: where the view projects it, and
/// its place among the pixel centres. A caller drawing many small meshes keeps them from draw
/// to draw, so that no draw allocates them again.
#[derive(Default)]
pub struct DrawBuffers {
    projected: Vec<DVec3>,
    places: Vec<CentrePlaces>,
}

impl DrawBuffers {
    /// `mesh`'s vertices as `view` projects them, kept for the draw that follows.
    pub fn project(&mut self, view: &View, mesh: &Mesh) -> &[DVec3] {
        view.project_into(mesh.positions.iter().map(|p| p.as_dvec3()), &mut self.projected);
        &self.projected
    }
}

/// The pixel centres triangle t of `mesh` covers, less those whose squares the edges flagged
/// in `eroded(t)` cross ([`Coverage::Eroded`]), into any [`Pixels`], every vertex projected once.
fn fill_mesh(
    view: &View,
    mesh: &Mesh,
    eroded: impl Fn(usize) -> [bool; 3],
    visit: &mut impl Pixels,
    buffers: &mut DrawBuffers,
) {
    buffers.project(view, mesh);
    let triangles = 0..mesh.triangles.len();
    fill_triangles(
        view,
        (mesh, &buffers.projected),
        triangles,
        eroded,
        visit,
        &mut buffers.places,
    );
}

/// [`fill_mesh`] with no edge eroded, in buffers of its own.
fn fill_plain(view: &View, mesh: &Mesh, visit: &mut impl Pixels) {
    fill_mesh(view, mesh, |_| [false; 3], visit, &mut DrawBuffers::default());
}

/// [`fill_mesh`] of the triangles `triangles` (indices into the mesh's) alone, with the mesh's
/// vertices `projected` by the view; `places` is room for their places among the centres.
fn fill_triangles(
    view: &View,
    (mesh, projected): (&Mesh, &[DVec3]),
    triangles: impl Iterator<Item = usize>,
    eroded: impl Fn(usize) -> [bool; 3],
    visit: &mut impl Pixels,
    places: &mut Vec<CentrePlaces>,
) {
    match view.lens {
        Lens::Orthographic { .. } => {
            // Most triangles of a detailed mesh cover no pixel centre: their corners' places
            // among the centres, found once a vertex, leave them out by integer compares.
            places.clear();
            places.extend(projected.iter().map(|q| CentrePlaces::of(q, view.pixels)));
            // In AVX2's wider lanes where the CPU has them.
            with_avx2(|| {
                for t in triangles {
                    let tri = &mesh.triangles[t];
                    let Some(span) = CentrePlaces::span(tri.map(|i| places[i as usize]), view.pixels) else {
                        continue;
                    };
                    let q = tri.map(|i| projected[i as usize]);
                    fill_span(view, q, Coverage::Eroded(eroded(t)), |d| d, span, visit);
                }
            })
        }
        Lens::Perspective { .. } => {
            for t in triangles {
                let tri = &mesh.triangles[t];
                let corners = tri.map(|i| mesh.positions[i as usize].as_dvec3());
                fill_perspective(
                    view,
                    &corners,
                    tri.map(|i| projected[i as usize]),
                    Coverage::Eroded(eroded(t)),
                    Span::all(view),
                    visit,
                );
            }
        }
    }
}

/// A projected point's place among the pixel centres (i + 0.5) along x and along y: the
/// least index whose centre lies at or past it, and the greatest whose centre lies at or
/// before it. Both are clamped to [-1, n] for n pixels, which leaves every answer about the
/// pixels 0..n as it was.
#[derive(Clone, Copy)]
struct CentrePlaces {
    after: [i32; 2],
    before: [i32; 2],
}

impl CentrePlaces {
    #[inline(always)]
    fn of(q: &DVec3, n: usize) -> CentrePlaces {
        let places = |c: f64| {
            let v = (c - 0.5).clamp(-1.0, index_to_f64(n));
            let toward_zero = v as i32;
            let t = f64::from(toward_zero);
            (toward_zero + i32::from(t < v), toward_zero - i32::from(t > v))
        };
        let ((ax, bx), (ay, by)) = (places(q.x), places(q.y));
        CentrePlaces {
            after: [ax, ay],
            before: [bx, by],
        }
    }

    /// The pixels whose centres a triangle with these corners' places may cover, as [`fill`]
    /// finds them from its bounds: none where no centre lies within them.
    #[inline(always)]
    fn span(corners: [CentrePlaces; 3], n: usize) -> Option<Span> {
        let range = |k: usize| {
            let first = corners[0].after[k]
                .min(corners[1].after[k])
                .min(corners[2].after[k])
                .max(0);
            let last = corners[0].before[k]
                .max(corners[1].before[k])
                .max(corners[2].before[k])
                .min(n as i32 - 1);
            (first <= last).then_some((first as usize, last as usize))
        };
        Some(Span {
            x: range(0)?,
            y: range(1)?,
        })
    }
}

/// The nearest depth per pixel, `f32::INFINITY` where nothing is drawn.
pub fn depth_image(view: &View, mesh: &Mesh) -> Vec<f32> {
    let mut depth = Vec::new();
    draw_depth(view, mesh, &mut depth);
    depth
}

/// [`depth_image`] into `depth`, which is resized to the view's pixels: for a caller that
/// draws many views in turn through one image.
pub fn draw_depth(view: &View, mesh: &Mesh, depth: &mut Vec<f32>) {
    depth.clear();
    depth.resize(view.pixels * view.pixels, f32::INFINITY);
    fill_plain(view, mesh, &mut Nearest(depth));
}

/// Draws the triangles `kept` (indices into the mesh's) over `depth`, a depth image of `view`,
/// with the mesh's vertices as [`DrawBuffers::project`] last projected them into `buffers`.
pub fn draw_depth_of(
    view: &View,
    mesh: &Mesh,
    kept: impl Iterator<Item = usize>,
    depth: &mut [f32],
    buffers: &mut DrawBuffers,
) {
    fill_triangles(
        view,
        (mesh, &buffers.projected),
        kept,
        |_| [false; 3],
        &mut Nearest(depth),
        &mut buffers.places,
    );
}

/// [`draw_depth`] for a perspective view that many surfaces lie across, one behind another (a
/// camera inside a mesh): triangles nearest first, each left out where every tile its pixels may
/// fall in holds nothing farther than its nearest depth, less what rounding may take off that.
/// It would draw no pixel nearer than what is there, so the image is the same. Returns how many
/// triangles were left out.
pub fn draw_depth_nearest_first(view: &View, mesh: &Mesh, depth: &mut Vec<f32>) -> usize {
    let Lens::Perspective { .. } = view.lens else {
        draw_depth(view, mesh, depth);
        return 0;
    };
    let n = view.pixels;
    depth.clear();
    depth.resize(n * n, f32::INFINITY);
    let projected = view.project_all(mesh.positions.iter().map(|p| p.as_dvec3()));
    let near = view.depth_tolerance();
    let corners = |t: usize| mesh.triangles[t].map(|i| projected[i as usize]);
    // Clipped at the near plane, no point of a triangle lies nearer than its corners or the plane.
    let nearest = |q: &[DVec3; 3]| q.iter().map(|c| c.z.max(near)).fold(f64::INFINITY, f64::min);
    // Positive depths order as their bits do; the order only decides how much is left out.
    let mut order: Vec<(u32, usize)> = (0..mesh.triangles.len())
        .map(|t| ((nearest(&corners(t)) as f32).to_bits(), t))
        .collect();
    order.sort_unstable_by_key(|&(key, _)| key);
    let mut tiles = Tiles::new(n);
    let mut left_out = 0;
    for (_, t) in order {
        let q = corners(t);
        let bound = nearest_bound(&q, near, n);
        if bound.is_some_and(|(bound, span)| tiles.behind(depth, bound, span)) {
            left_out += 1;
            continue;
        }
        let tri = mesh.corners(t).map(|p| p.as_dvec3());
        match bound {
            // Its pixels lie in the span: its tiles are marked once, not a pixel at a time, through
            // the plain sink (one closure testing which arm applies costs teapot 4.5% more
            // instructions).
            Some((_, span)) => {
                fill_perspective(view, &tri, q, Coverage::Centres, Span::all(view), &mut Nearest(depth));
                tiles.drawn_in(span);
            }
            None => {
                let mut pixels = EachPixel(|i: usize, d: f64| {
                    depth[i] = depth[i].min(d as f32);
                    tiles.drawn(i);
                });
                fill_perspective(view, &tri, q, Coverage::Centres, Span::all(view), &mut pixels);
            }
        }
    }
    left_out
}

/// Pixels a side of the tiles of [`draw_depth_nearest_first`].
const CULL_TILE: usize = 8;

/// Per tile of an n × n depth image, a depth no nearer than any of its pixels', found again
/// once a pixel of the tile has been drawn.
struct Tiles {
    n: usize,
    across: usize,
    farthest: Vec<f32>,
    stale: Vec<bool>,
}

impl Tiles {
    fn new(n: usize) -> Tiles {
        let across = n.div_ceil(CULL_TILE);
        Tiles {
            n,
            across,
            farthest: vec![f32::INFINITY; across * across],
            stale: vec![false; across * across],
        }
    }

    fn drawn(&mut self, pixel: usize) {
        let (x, y) = (pixel % self.n, pixel / self.n);
        self.stale[(y / CULL_TILE) * self.across + x / CULL_TILE] = true;
    }

    /// Marks every tile of the pixels `span`.
    fn drawn_in(&mut self, span: Span) {
        for ty in span.y.0 / CULL_TILE..=span.y.1 / CULL_TILE {
            let row = ty * self.across;
            self.stale[row + span.x.0 / CULL_TILE..=row + span.x.1 / CULL_TILE].fill(true);
        }
    }

    /// Whether every tile of the pixels `span` of `depth` holds nothing farther than `bound`. A
    /// stale tile's depth is found again only where it does not answer: drawing brings pixels
    /// nearer, so it is still no nearer than any of them.
    fn behind(&mut self, depth: &[f32], bound: f64, span: Span) -> bool {
        for ty in span.y.0 / CULL_TILE..=span.y.1 / CULL_TILE {
            for tx in span.x.0 / CULL_TILE..=span.x.1 / CULL_TILE {
                let k = ty * self.across + tx;
                if f64::from(self.farthest[k]) > bound && self.stale[k] {
                    self.farthest[k] = self.farthest_of(depth, tx, ty);
                    self.stale[k] = false;
                }
                if f64::from(self.farthest[k]) > bound {
                    return false;
                }
            }
        }
        true
    }

    /// The farthest depth of tile (tx, ty) of `depth`, or 0 where every depth is nearer: each
    /// row of a whole tile taken in lanes.
    fn farthest_of(&self, depth: &[f32], tx: usize, ty: usize) -> f32 {
        let n = self.n;
        let rows = ty * CULL_TILE..((ty + 1) * CULL_TILE).min(n);
        let columns = tx * CULL_TILE..((tx + 1) * CULL_TILE).min(n);
        if columns.len() < CULL_TILE {
            return rows
                .flat_map(|y| depth[y * n + columns.start..y * n + columns.end].iter().copied())
                .fold(0.0, greater);
        }
        let mut far = [0f32; CULL_TILE];
        for y in rows {
            let row: &[f32; CULL_TILE] = depth[y * n + columns.start..][..CULL_TILE].try_into().unwrap();
            for (far, &d) in far.iter_mut().zip(row) {
                *far = greater(*far, d);
            }
        }
        far.into_iter().fold(0.0, greater)
    }
}

/// For the corners `q` of a perspective triangle wholly in front of the near plane, a depth no
/// nearer than any it draws, and the first and last columns and rows its pixels may lie in,
/// with a pixel to spare. None for a triangle that the near plane clips, or that is not finite.
///
/// A drawn pixel's depth is 1 over the sum of the corners' reciprocal depths weighed by
/// nonnegative weights, so it is no nearer than the nearest corner over the weights' sum. The sum
/// is 1, save for rounding of the edge functions, each off by a few parts in 10¹⁶ of the bounds'
/// extent squared: less than 10⁻¹³ of that over the area.
fn nearest_bound(q: &[DVec3; 3], near: f64, n: usize) -> Option<(f64, Span)> {
    if !q.iter().all(|c| c.z >= near && c.is_finite()) {
        return None;
    }
    let (lo, hi) = (q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2]));
    let extent = (hi.x - lo.x).max(hi.y - lo.y);
    let area = cross((q[1] - q[0]).truncate(), (q[2] - q[0]).truncate()).abs();
    let slack = 1e-9 + 1e-13 * extent * extent / area;
    // Also where the area is 0 or the corners coincide.
    if slack.is_nan() || slack >= 0.5 {
        return None;
    }
    // Pixel centres i + 0.5 within the bounds.
    let pixel = |v: f64| clamped_index(v, n);
    let span = Span {
        x: (pixel(lo.x - 1.5), pixel(hi.x + 0.5)),
        y: (pixel(lo.y - 1.5), pixel(hi.y + 0.5)),
    };
    Some((lo.z * (1.0 - slack), span))
}

/// For a perspective view, a depth no nearer than that of any pixel [`rasterize`] visits of
/// `tri`, and the columns and rows those pixels lie in; None where the near plane clips the
/// triangle or it is not finite.
pub fn nearest_drawn(view: &View, tri: &[DVec3; 3]) -> Option<(f64, [std::ops::RangeInclusive<usize>; 2])> {
    let Lens::Perspective { .. } = view.lens else {
        return None;
    };
    let q = tri.map(|p| view.project(p));
    let (nearest, span) = nearest_bound(&q, view.depth_tolerance(), view.pixels)?;
    Some((nearest, [span.x.0..=span.x.1, span.y.0..=span.y.1]))
}

/// Depth images of `mesh` in `views`: on `gpu` where one is given, else on the CPU.
/// `Unsupported` where the GPU cannot draw them (perspective views, a mesh larger than one
/// storage binding): the caller's stage then runs on the CPU and says so.
pub fn depth_images(views: &[View], mesh: &Mesh, gpu: Option<&Gpu>) -> Result<Vec<Vec<f32>>, GpuError> {
    match gpu {
        Some(gpu) => gpu::depth_images(gpu, mesh, views),
        None => Ok(views.par_iter().map(|view| depth_image(view, mesh)).collect()),
    }
}

/// A coverage bitmask, one bit per pixel. `open` marks the triangles of parts of the surface
/// with an open boundary; None where every part has one. Of the others, on closed parts (each
/// edge used as often one way as the other), only those whose corners turn anticlockwise on the
/// screen are drawn: a line through a closed part crosses as many of its triangles facing one
/// way as the other, so those cover all it does.
pub fn coverage_mask(view: &View, mesh: &Mesh, open: Option<&[bool]>) -> Vec<u64> {
    let mut mask = vec![0u64; (view.pixels * view.pixels).div_ceil(64)];
    let bits = &mut Bits::new(&mut mask);
    match open {
        None => fill_plain(view, mesh, bits),
        Some(open) => {
            let projected = view.project_all(mesh.positions.iter().map(|p| p.as_dvec3()));
            let anticlockwise = |t: usize| {
                let q = mesh.triangles[t].map(|i| projected[i as usize].truncate());
                cross(q[1] - q[0], q[2] - q[0]) > 0.0
            };
            let drawn = (0..mesh.triangles.len()).filter(|&t| open[t] || anticlockwise(t));
            fill_triangles(view, (mesh, &projected), drawn, |_| [false; 3], bits, &mut Vec::new());
        }
    }
    mask
}

/// Sets the bits of `mask` (one bit per pixel) for the pixels `mesh` covers; returns the words
/// drawn, from the first to one past the last (empty when none). `buffers` may be any kept from
/// an earlier draw.
pub fn draw_coverage(view: &View, mesh: &Mesh, mask: &mut [u64], buffers: &mut DrawBuffers) -> std::ops::Range<usize> {
    let mut bits = Bits::new(mask);
    fill_mesh(view, mesh, |_| [false; 3], &mut bits, buffers);
    bits.first.min(bits.end)..bits.end
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One triangle as [`draw_eroded`] draws each of its own.
    fn rasterize_eroded(view: &View, tri: &[DVec3; 3], eroded: [bool; 3], visit: impl FnMut(usize, f64)) {
        rasterize_with(view, tri, Coverage::Eroded(eroded), Span::all(view), visit);
    }

    /// A tall triangle whose edge 0 (from corner 1 to corner 2) is a vertical line at world x =
    /// `edge_x`, seen from the front in a 16-pixel view: the pixels drawn, plainly and eroded.
    fn drawn(edge_x: f64, eroded: [bool; 3]) -> (View, Vec<usize>, Vec<usize>) {
        let view = View::new(DVec3::Z, DVec3::ZERO, 1.0, 16);
        let far = -4.0 * (edge_x - 0.5).signum();
        let tri = [
            DVec3::new(far, -4.0, 0.0),
            DVec3::new(edge_x, -4.0, 0.0),
            DVec3::new(edge_x, 4.0, 0.0),
        ];
        let (mut plain, mut thin) = (Vec::new(), Vec::new());
        rasterize(&view, &tri, |i, _| plain.push(i));
        rasterize_eroded(&view, &tri, eroded, |i, _| thin.push(i));
        (view, plain, thin)
    }

    /// Every pixel of the view tested alone, as the definition reads: a centre is drawn where
    /// each weight (edge function / area) reaches the edge's inset.
    fn drawn_pixel_by_pixel(view: &View, tri: &[DVec3; 3], eroded: [bool; 3]) -> Vec<(usize, f64)> {
        let p = tri.map(|v| view.project(v));
        let q = p.map(|v| v.truncate());
        let area = cross(q[1] - q[0], q[2] - q[0]);
        let mut out = Vec::new();
        if area == 0.0 || !area.is_finite() {
            return out;
        }
        let inset = |k: usize| {
            let edge = q[(k + 2) % 3] - q[(k + 1) % 3];
            if eroded[k] {
                0.5 * (edge.x.abs() + edge.y.abs()) / area.abs()
            } else {
                0.0
            }
        };
        for i in 0..view.pixels * view.pixels {
            let c = DVec2::new((i % view.pixels) as f64 + 0.5, (i / view.pixels) as f64 + 0.5);
            let f = [
                cross(q[2] - q[1], c - q[1]),
                cross(q[0] - q[2], c - q[2]),
                cross(q[1] - q[0], c - q[0]),
            ];
            if (0..3).all(|k| f[k] / area >= inset(k)) {
                // Depths weigh by the edge functions times 1 / area, as fill_centres does.
                let w = f.map(|f| f * (1.0 / area));
                out.push((i, w[0] * p[0].z + w[1] * p[1].z + w[2] * p[2].z));
            }
        }
        out
    }

    #[test]
    fn a_search_from_any_guess_finds_what_bisection_finds() {
        let mut rng = fastrand::Rng::with_seed(23);
        for _ in 0..20_000 {
            let from = rng.usize(0..300);
            let to = from + rng.usize(0..300);
            let threshold = rng.usize(from.saturating_sub(5)..to + 5);
            let guess = match rng.usize(0..4) {
                0 => usize::MAX,
                1 => (threshold + rng.usize(0..5)).saturating_sub(2),
                _ => rng.usize(0..700),
            };
            let test = |x: usize| x >= threshold;
            assert_eq!(
                first_where_near(from, to, guess, test),
                first_where(from, to, test),
                "[{from}, {to}) from {guess}, holding from {threshold}"
            );
        }
    }

    #[test]
    fn rows_drawn_by_runs_give_every_pixel_and_depth_of_the_pixel_by_pixel_test() {
        let mut rng = fastrand::Rng::with_seed(7);
        let view = View::new(DVec3::new(0.3, 0.8, 0.5).normalize(), DVec3::ZERO, 1.0, 48);
        let mut drawn_in_all = 0;
        for case in 0..3000 {
            // Large, small, slivers, and corners on pixel centres and far off the view.
            let scale = [0.05, 0.4, 2.0, 30.0][case % 4];
            let mut corner = || {
                let v = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * scale;
                if case % 5 == 0 { (v * 48.0).round() / 48.0 } else { v }
            };
            let mut tri = [corner(), corner(), corner()];
            if case % 7 == 0 {
                tri[2] = tri[0] + (tri[1] - tri[0]) * 0.5 + DVec3::splat(1e-9);
            }
            let eroded = [case % 3 == 0, case % 6 == 1, false];
            let mut fast = Vec::new();
            rasterize_eroded(&view, &tri, eroded, |i, d| fast.push((i, d)));
            fast.sort_by_key(|&(i, _)| i);
            let slow = drawn_pixel_by_pixel(&view, &tri, eroded);
            assert!(
                fast.len() == slow.len()
                    && fast
                        .iter()
                        .zip(&slow)
                        .all(|(a, b)| a.0 == b.0 && a.1.to_bits() == b.1.to_bits()),
                "case {case}: {} pixels drawn, {} by the pixel-by-pixel test",
                fast.len(),
                slow.len()
            );
            drawn_in_all += fast.len();
        }
        assert!(drawn_in_all > 100_000, "{drawn_in_all}");
    }

    /// `count` random triangles about the origin, a third at each of the `scales`.
    fn random_triangles(seed: u64, count: u32, scales: [f32; 3]) -> Mesh {
        let mut rng = fastrand::Rng::with_seed(seed);
        let mut mesh = Mesh::default();
        for t in 0..count {
            for _ in 0..3 {
                let v = glam::Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
                mesh.positions.push(v * scales[t as usize % 3]);
            }
            mesh.triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
        }
        mesh
    }

    #[test]
    fn a_mesh_drawn_from_inside_gives_what_its_triangles_give_one_by_one() {
        // Triangles all around the eye: in front, behind, and across its near plane.
        let mesh = random_triangles(3, 600, [0.2, 1.0, 4.0]);
        let (mut drawn, mut crossing) = (0, 0);
        for view in View::cube_map(DVec3::new(0.01, 0.02, -0.03), 64, 1e-3) {
            let mut whole = Vec::new();
            rasterize_mesh(&view, &mesh, |i, d| whole.push((i, d.to_bits())));
            let mut one_by_one = Vec::new();
            for tri in mesh.triangles_f64() {
                rasterize(&view, &tri, |i, d| one_by_one.push((i, d.to_bits())));
                let near = view.depth_tolerance();
                let in_front = tri.iter().filter(|&&v| view.project(v).z >= near).count();
                crossing += usize::from(in_front == 1 || in_front == 2);
            }
            assert_eq!(whole, one_by_one);
            drawn += whole.len();
        }
        assert!(drawn > 10_000 && crossing > 100, "{drawn} pixels, {crossing} crossing");
    }

    #[test]
    fn a_mesh_drawn_around_gives_what_its_triangles_give_one_by_one() {
        // Seen along z, 64 pixels frame the unit sphere: pixels 1/32 wide, their centres at odd
        // multiples of 1/64 less 1. Half the corners lie on a multiple of 1/64, so on a pixel's
        // centre or edge, where the corners' places among the centres must round as the
        // triangle's bounds do; some triangles reach far off the view.
        let mut mesh = random_triangles(13, 3000, [0.02, 0.3, 6.0]);
        for p in mesh.positions.iter_mut().step_by(2) {
            *p = (*p * 64.0).round() / 64.0;
        }
        let aslant = DVec3::new(0.3, 0.8, -0.5).normalize();
        let mut drawn = 0;
        // Also an image whose rows are no whole number of `LANES`.
        let views = [(DVec3::Z, 64), (aslant, 64), (aslant, 61)].map(|(d, n)| View::new(d, DVec3::ZERO, 1.0, n));
        for view in views {
            let mut whole = Vec::new();
            rasterize_mesh(&view, &mesh, |i, d| whole.push((i, d.to_bits())));
            let mut one_by_one = Vec::new();
            let mut nearest = vec![f32::INFINITY; view.pixels * view.pixels];
            for tri in mesh.triangles_f64() {
                rasterize(&view, &tri, |i, d| {
                    one_by_one.push((i, d.to_bits()));
                    nearest[i] = nearest[i].min(d as f32);
                });
            }
            assert_eq!(whole, one_by_one);
            // The depth image, drawn a few pixels at a time.
            let image = depth_image(&view, &mesh);
            assert!(image.iter().zip(&nearest).all(|(a, b)| a.to_bits() == b.to_bits()));
            drawn += whole.len();
        }
        assert!(drawn > 20_000, "{drawn} pixels");
    }

    #[test]
    fn an_eroded_mesh_draws_what_its_triangles_draw_one_by_one() {
        let mesh = random_triangles(5, 900, [0.05, 0.3, 1.5]);
        let mut rng = fastrand::Rng::with_seed(6);
        let eroded: Vec<[bool; 3]> = (0..mesh.triangles.len())
            .map(|_| [rng.bool(), rng.bool(), rng.bool()])
            .collect();
        let around = [DVec3::X, DVec3::new(0.3, 0.8, -0.5).normalize()].map(|d| View::new(d, DVec3::ZERO, 1.0, 96));
        let (mut drawn, mut fewer) = (0, 0);
        for view in around
            .into_iter()
            .chain(View::cube_map(DVec3::new(0.01, -0.02, 0.03), 64, 1e-3))
        {
            let n = view.pixels * view.pixels;
            let mut whole = vec![f32::INFINITY; n];
            draw_eroded(&view, &mesh, &eroded, &mut whole);
            let (mut one_by_one, mut plain) = (vec![f32::INFINITY; n], vec![f32::INFINITY; n]);
            for (tri, &flags) in mesh.triangles_f64().zip(&eroded) {
                rasterize_eroded(&view, &tri, flags, |i, d| one_by_one[i] = one_by_one[i].min(d as f32));
                rasterize(&view, &tri, |i, d| plain[i] = plain[i].min(d as f32));
            }
            assert!(whole.iter().zip(&one_by_one).all(|(a, b)| a.to_bits() == b.to_bits()));
            drawn += whole.iter().filter(|d| d.is_finite()).count();
            fewer += whole.iter().zip(&plain).filter(|(a, b)| a != b).count();
        }
        assert!(
            drawn > 10_000 && fewer > 1_000,
            "{drawn} pixels drawn, {fewer} of them eroded"
        );
    }

    #[test]
    fn culling_tiles_answer_as_the_farthest_depth_under_a_span_does() {
        // An image whose size leaves tiles cut short at its edges, drawn nearer span by span,
        // and asked between draws about spans and depths around what it holds.
        let n = 61;
        let mut rng = fastrand::Rng::with_seed(17);
        let mut depth = vec![f32::INFINITY; n * n];
        let mut tiles = Tiles::new(n);
        let random_span = |rng: &mut fastrand::Rng| {
            let along = |rng: &mut fastrand::Rng| {
                let first = rng.usize(..n);
                (first, (first + rng.usize(..12)).min(n - 1))
            };
            Span {
                x: along(rng),
                y: along(rng),
            }
        };
        let (mut behind, mut not) = (0, 0);
        for _ in 0..4000 {
            let span = random_span(&mut rng);
            for y in span.y.0..=span.y.1 {
                for x in span.x.0..=span.x.1 {
                    if rng.bool() {
                        depth[y * n + x] = depth[y * n + x].min(rng.f32() * 10.0);
                    }
                }
            }
            tiles.drawn_in(span);
            let asked = random_span(&mut rng);
            let bound = f64::from(rng.f32() * 12.0);
            // The farthest depth over the asked span's tiles, pixel by pixel.
            let (columns, rows) = (
                asked.x.0 / CULL_TILE * CULL_TILE..((asked.x.1 / CULL_TILE + 1) * CULL_TILE).min(n),
                asked.y.0 / CULL_TILE * CULL_TILE..((asked.y.1 / CULL_TILE + 1) * CULL_TILE).min(n),
            );
            let farthest = rows
                .flat_map(|y| depth[y * n + columns.start..y * n + columns.end].iter().copied())
                .fold(0.0, f32::max);
            let expected = f64::from(farthest) <= bound;
            assert_eq!(
                tiles.behind(&depth, bound, asked),
                expected,
                "{:?}, {bound}",
                (asked.x, asked.y)
            );
            (behind, not) = if expected { (behind + 1, not) } else { (behind, not + 1) };
        }
        assert!(behind > 500 && not > 500, "{behind} behind, {not} not");
    }

    #[test]
    fn a_depth_image_drawn_nearest_first_is_the_plain_one_to_the_bit() {
        // Many layers around the eye, slivers among them, some across its near plane.
        let mut mesh = random_triangles(11, 3000, [0.3, 2.0, 6.0]);
        let slivers = random_triangles(12, 600, [3.0, 3.0, 3.0]);
        for (k, tri) in slivers.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| slivers.positions[i as usize]);
            let at = mesh.positions.len() as u32;
            mesh.positions.extend([a, b, a + (c - a) * 1e-4 * (k % 7) as f32]);
            mesh.triangles.push([at, at + 1, at + 2]);
        }
        let (mut plain, mut culled) = (Vec::new(), Vec::new());
        let (mut drawn, mut left_out) = (0, 0);
        // The second size leaves tiles cut short at the image's edges.
        let views = [64, 61].map(|pixels| View::cube_map(DVec3::new(0.01, 0.02, -0.03), pixels, 1e-3));
        for view in views.into_iter().flatten() {
            draw_depth(&view, &mesh, &mut plain);
            left_out += draw_depth_nearest_first(&view, &mesh, &mut culled);
            assert_eq!(
                plain.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
                culled.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
            );
            drawn += plain.iter().filter(|d| d.is_finite()).count();
        }
        // Most of the image drawn, and many triangles left out, so the test says something.
        assert!(
            drawn > 6 * (64 * 64 + 61 * 61) * 9 / 10 && left_out > 4000,
            "{drawn} pixels drawn, {left_out} left out"
        );
    }

    #[test]
    fn coverage_drawn_by_runs_sets_the_bits_of_the_pixels_drawn_one_by_one() {
        let mesh = random_triangles(9, 300, [0.05, 0.5, 3.0]);
        let mut set = 0;
        let views = [
            View::new(DVec3::new(0.2, 0.9, 0.4).normalize(), DVec3::ZERO, 1.0, 70),
            View::cube_map(DVec3::new(0.01, 0.02, -0.03), 70, 1e-3).swap_remove(2),
        ];
        for view in views {
            let mut by_runs = coverage_mask(&view, &mesh, None);
            let mut one_by_one = vec![0u64; by_runs.len()];
            rasterize_mesh(&view, &mesh, |i, _| one_by_one[i / 64] |= 1 << (i % 64));
            assert_eq!(by_runs, one_by_one);
            set += by_runs.iter().map(|w| w.count_ones()).sum::<u32>();
            // The words drawn are those from the first set to the last.
            let drawn = draw_coverage(&view, &mesh, &mut by_runs, &mut DrawBuffers::default());
            let first = one_by_one.iter().position(|&w| w != 0).unwrap();
            let last = one_by_one.iter().rposition(|&w| w != 0).unwrap();
            assert_eq!(drawn, first..last + 1);
        }
        assert!(set > 2000, "{set} pixels");
    }

    #[test]
    fn a_closed_part_drawn_from_its_triangles_facing_one_way_covers_what_all_of_them_do() {
        // Two tori through each other, the second turned inside out, and open triangles across.
        let mut mesh = crate::mesh::shapes::torus(1.0, 0.4, 24, 12);
        let mut inverted = crate::mesh::shapes::torus(0.8, 0.3, 20, 10);
        for p in &mut inverted.positions {
            *p = glam::Vec3::new(p.x + 0.6, p.z, -p.y);
        }
        for tri in &mut inverted.triangles {
            tri.swap(1, 2);
        }
        mesh.append(&inverted);
        let closed_parts = mesh.triangles.len();
        mesh.append(&random_triangles(5, 30, [0.5, 1.0, 2.0]));
        let open: Vec<bool> = (0..mesh.triangles.len()).map(|t| t >= closed_parts).collect();
        let (mut set, mut open_left_out) = (0, 0);
        for d in crate::geom::camera::fibonacci_sphere(24) {
            let view = View::new(d, DVec3::ZERO, 2.0, 96);
            let all = coverage_mask(&view, &mesh, None);
            assert_eq!(coverage_mask(&view, &mesh, Some(&open)), all);
            set += all.iter().map(|w| w.count_ones()).sum::<u32>();
            // Taken for closed, the open triangles facing the other way go missing.
            open_left_out += usize::from(coverage_mask(&view, &mesh, Some(&vec![false; open.len()])) != all);
        }
        assert!(
            set > 24 * 2000 && open_left_out > 12,
            "{set} pixels, {open_left_out} views"
        );
    }

    #[test]
    fn an_eroded_edge_gives_up_exactly_the_pixels_whose_squares_it_crosses() {
        let mut removed_in_all = 0;
        for edge_x in [0.03, 0.09, -0.2, 0.51] {
            let (view, plain, thin) = drawn(edge_x, [true, false, false]);
            let screen_x = view.project(DVec3::new(edge_x, 0.0, 0.0)).x;
            let removed: Vec<usize> = plain.iter().copied().filter(|i| !thin.contains(i)).collect();
            assert!(thin.iter().all(|i| plain.contains(i)), "erosion only removes pixels");
            removed_in_all += removed.len();
            for i in &plain {
                let centre = (i % 16) as f64 + 0.5;
                assert_eq!(
                    removed.contains(i),
                    (centre - screen_x).abs() < 0.5,
                    "edge at {edge_x}, pixel {i}"
                );
            }
            // Edges that are not flagged keep every pixel.
            assert_eq!(drawn(edge_x, [false; 3]).2, plain);
        }
        assert!(removed_in_all >= 16, "a column of pixels straddles some of the edges");
    }
}
