//! The largest all-true rectangle of a 2D mask: the histogram method, linear in the cells.

/// Cells [u0, u1) × [v0, v1) of a `nu` × `nv` mask (v fastest).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRect {
    pub u: [usize; 2],
    pub v: [usize; 2],
}

impl CellRect {
    pub fn cells(&self) -> usize {
        (self.u[1] - self.u[0]) * (self.v[1] - self.v[0])
    }

    pub fn iter(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (self.u[0]..self.u[1]).flat_map(move |u| (self.v[0]..self.v[1]).map(move |v| (u, v)))
    }
}

/// The largest rectangle of true cells at least `min_side` cells wide each way, if any.
pub fn largest(mask: &[bool], nu: usize, nv: usize, min_side: usize) -> Option<CellRect> {
    Sweep::new(nu, nv, min_side).run(0..nu, &bit_rows(mask, nu, nv), nv.div_ceil(64))
}

/// A `nu` × `nv` mask as [`Sweep::run`] reads it: each row's cells as bits, in whole words.
pub fn bit_rows(mask: &[bool], nu: usize, nv: usize) -> Vec<u64> {
    let words = nv.div_ceil(64);
    let mut bits = vec![0u64; nu * words];
    for (c, _) in mask.iter().enumerate().filter(|(_, open)| **open) {
        let (u, v) = (c / nv, c % nv);
        bits[u * words + v / 64] |= 1 << (v % 64);
    }
    bits
}

/// A column's count of open cells ending on a row: two bytes, so that a row's heights grow
/// eight at a time in one 128-bit register. [`Sweep::new`] takes at most `Height::MAX` rows.
type Height = u16;

/// The histogram method's pass over row `u`: the rectangles that end on it, each as tall as a
/// column's height and as wide as the columns around it at least as high, replace `best` when
/// larger (so the first found of the largest size stays). `live` has a bit for each column at
/// least `min_side` high; the others bound rectangles as an empty column does, since none
/// that holds them is tall enough, so runs of them are skipped a word at a time. The stack
/// holds each rectangle still open as (first column, height), heights rising: columns as high
/// as the top only widen it.
fn pop_row(
    u: usize,
    heights: &[Height],
    live: &[u64],
    min_side: usize,
    stack: &mut Vec<(usize, Height)>,
    best: &mut Option<CellRect>,
) {
    let nv = heights.len();
    let mut best_cells = best.map_or(0, |b| b.cells());
    stack.clear();
    let mut v = 0;
    while v <= nv {
        if stack.is_empty() {
            match next_bit(live, v) {
                Some(next) if next < nv => v = next,
                _ => return,
            }
        }
        let h = heights.get(v).copied().filter(|&h| h as usize >= min_side).unwrap_or(0);
        // Where a rectangle as high as this column begins: the first column of those it ends.
        let mut start = v;
        while let Some(&(left, height)) = stack.last() {
            if height <= h {
                break;
            }
            stack.pop();
            start = left;
            let height = height as usize;
            let cells = height * (v - left);
            // Every rectangle lies in one of these maximal ones, with sides at least as long.
            if v - left >= min_side && cells > best_cells {
                best_cells = cells;
                *best = Some(CellRect {
                    u: [u + 1 - height, u + 1],
                    v: [left, v],
                });
            }
        }
        if h > 0 && stack.last().is_none_or(|&(_, height)| height < h) {
            stack.push((start, h));
        }
        v += 1;
    }
}

/// The first set bit at or after `v`.
fn next_bit(bits: &[u64], v: usize) -> Option<usize> {
    let (first, shift) = (v / 64, v % 64);
    let word = *bits.get(first)? >> shift << shift;
    if word != 0 {
        return Some(first * 64 + word.trailing_zeros() as usize);
    }
    let k = bits[first + 1..].iter().position(|&w| w != 0)?;
    Some((first + 1 + k) * 64 + bits[first + 1 + k].trailing_zeros() as usize)
}

/// Each byte's bits as lanes of all ones or zeros, so that eight heights grow at once.
const BYTE_LANES: [[Height; 8]; 256] = {
    let mut lanes = [[0; 8]; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut bit = 0;
        while bit < 8 {
            lanes[byte][bit] = if byte >> bit & 1 == 1 { Height::MAX } else { 0 };
            bit += 1;
        }
        byte += 1;
    }
    lanes
};

/// A row's column heights from the row above's (none on the first row): one more where the
/// row's bit is set, else 0. Eight columns at a time in fixed-length arrays, so that the
/// lanes are one vector operation.
fn grow_heights(row: &mut [Height], above: Option<&[Height]>, bits: &[u64]) {
    const NONE_ABOVE: [Height; 64] = [0; 64];
    for (k, (heights, &word)) in row.chunks_mut(64).zip(bits).enumerate() {
        let above = above.map_or(&NONE_ABOVE[..heights.len()], |a| &a[64 * k..64 * k + heights.len()]);
        if word == 0 {
            heights.fill(0);
            continue;
        }
        let (eights, rest) = heights.as_chunks_mut::<8>();
        let (above_eights, above_rest) = above.as_chunks::<8>();
        for (b, (heights, above)) in eights.iter_mut().zip(above_eights).enumerate() {
            let lanes = &BYTE_LANES[(word >> (8 * b)) as usize & 0xff];
            // Read whole before it is written: written lane by lane, LLVM keeps it scalar.
            *heights = std::array::from_fn(|j| (above[j] + 1) & lanes[j]);
        }
        let first = 8 * eights.len();
        for (j, (height, above)) in rest.iter_mut().zip(above_rest).enumerate() {
            *height = if word >> (first + j) & 1 == 1 { above + 1 } else { 0 };
        }
    }
}

/// What the search of one row found: the first of the largest rectangles ending on it, or that
/// none ending on it has more than so many cells. The first holds whatever the rows before
/// found; the second only while they found at least as many.
#[derive(Clone, Copy)]
enum RowBest {
    Found(CellRect),
    AtMost(usize),
}

/// [`largest`] kept row by row, for a mask whose cells only ever close: after cells close in
/// some rows, [`Sweep::run`] redoes those and the rows below whose column heights they change,
/// and finds what a new search would, the same rectangle included.
pub struct Sweep {
    nv: usize,
    words: usize,
    min_side: usize,
    /// Each row's column heights, `nv` a row.
    heights: Vec<Height>,
    /// The best rectangle ending on or before each row.
    best: Vec<Option<CellRect>>,
    /// What each row's own search found.
    rows: Vec<RowBest>,
    live: Vec<u64>,
    stack: Vec<(usize, Height)>,
    /// A row's heights before they grow again.
    before: Vec<Height>,
}

impl Sweep {
    pub fn new(nu: usize, nv: usize, min_side: usize) -> Sweep {
        // Every caller's grid is capped far below: cook.quad_grid at 4096 cells a side.
        assert!(nu <= usize::from(Height::MAX), "a sweep of {nu} rows");
        let words = nv.div_ceil(64);
        Sweep {
            nv,
            words,
            min_side,
            heights: vec![0; nu * nv],
            best: vec![None; nu],
            rows: vec![RowBest::AtMost(0); nu],
            live: vec![0; words],
            stack: Vec::with_capacity(nv + 1),
            before: vec![0; nv],
        }
    }

    /// The cells it sweeps.
    pub fn cells(&self) -> usize {
        self.heights.len()
    }

    /// The largest rectangle of the open cells. `changed` holds the rows where cells closed
    /// since the last run; the first run, or one after any other change, passes every row.
    /// Cell (u, v) is open when bit v % 64 of `open[u * stride + v / 64]` is set.
    pub fn run(&mut self, changed: std::ops::Range<usize>, open: &[u64], stride: usize) -> Option<CellRect> {
        let (nv, nu) = (self.nv, self.best.len());
        // The row before may have been skipped for what the changed row held: redo it too.
        let from = changed.start.min(nu).saturating_sub(1);
        // Once a row past the changed ones has the heights it had, so do all after it, and
        // each keeps what its search found.
        let mut settled = false;
        for u in from..nu {
            if !settled {
                let (done, rest) = self.heights.split_at_mut(u * nv);
                let row = &mut rest[..nv];
                let past = u >= changed.end;
                if past {
                    self.before.copy_from_slice(row);
                }
                // The row above; none on the first.
                let above = &done[done.len().saturating_sub(nv)..];
                grow_heights(row, (u > 0).then_some(above), row_bits(open, u, stride, self.words));
                settled = past && *row == *self.before;
            }
            let best = if u > 0 { self.best[u - 1] } else { None };
            let threshold = best.map_or(0, |b| b.cells());
            let known = settled
                && match self.rows[u] {
                    RowBest::Found(_) => true,
                    RowBest::AtMost(cells) => cells <= threshold,
                };
            if !known {
                self.rows[u] = self.search_row(u, open, stride, best);
            }
            self.best[u] = match self.rows[u] {
                RowBest::Found(rect) if rect.cells() > threshold => Some(rect),
                _ => best,
            };
        }
        self.best.last().copied().flatten()
    }

    /// Searches the rectangles ending on row `u`, whose heights have grown, for one larger than
    /// `best`, the best of the rows before.
    fn search_row(&mut self, u: usize, open: &[u64], stride: usize, best: Option<CellRect>) -> RowBest {
        let (nv, nu, words) = (self.nv, self.best.len(), self.words);
        let bits = row_bits(open, u, stride, words);
        // Each rectangle of a row whose open cells the next row holds too grows into a larger
        // one ending there: the row need not be searched.
        let grows_on = u + 1 < nu
            && bits
                .iter()
                .zip(row_bits(open, u + 1, stride, words))
                .all(|(a, b)| a & !b == 0);
        if grows_on || u + 1 < self.min_side {
            return RowBest::AtMost(0);
        }
        // Columns at least `min_side` high: open on the last `min_side` rows.
        self.live.copy_from_slice(bits);
        for k in 1..self.min_side {
            for (live, word) in self.live.iter_mut().zip(row_bits(open, u - k, stride, words)) {
                *live &= word;
            }
        }
        // A rectangle ending on the row is no wider than its columns high enough and no taller
        // than the highest: when that cannot beat the best, the row is done.
        let row = &self.heights[u * nv..(u + 1) * nv];
        let width: u32 = self.live.iter().map(|w| w.count_ones()).sum();
        let most = width as usize * row.iter().copied().max().unwrap_or(0) as usize;
        let threshold = best.map_or(0, |b| b.cells());
        if most <= threshold {
            return RowBest::AtMost(most);
        }
        let mut found = best;
        pop_row(u, row, &self.live, self.min_side, &mut self.stack, &mut found);
        match found {
            Some(rect) if found != best => RowBest::Found(rect),
            _ => RowBest::AtMost(threshold),
        }
    }
}

/// Row `u`'s `words` words of bits, rows `stride` words apart.
fn row_bits(open: &[u64], u: usize, stride: usize, words: usize) -> &[u64] {
    &open[u * stride..u * stride + words]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest rectangle by trying every one.
    fn brute_force(mask: &[bool], nu: usize, nv: usize, min_side: usize) -> usize {
        let mut best = 0;
        for u0 in 0..nu {
            for u1 in u0 + 1..=nu {
                for v0 in 0..nv {
                    for v1 in v0 + 1..=nv {
                        let r = CellRect {
                            u: [u0, u1],
                            v: [v0, v1],
                        };
                        let wide_enough = u1 - u0 >= min_side && v1 - v0 >= min_side;
                        if wide_enough && r.iter().all(|(u, v)| mask[u * nv + v]) {
                            best = best.max(r.cells());
                        }
                    }
                }
            }
        }
        best
    }

    #[test]
    fn matches_brute_force_on_random_masks() {
        let mut rng = fastrand::Rng::with_seed(7);
        for _ in 0..200 {
            let (nu, nv) = (rng.usize(1..9), rng.usize(1..9));
            let mask: Vec<bool> = (0..nu * nv).map(|_| rng.f64() < 0.7).collect();
            for min_side in 1..3 {
                let found = largest(&mask, nu, nv, min_side);
                assert_eq!(found.map_or(0, |r| r.cells()), brute_force(&mask, nu, nv, min_side));
                if let Some(r) = found {
                    assert!(r.iter().all(|(u, v)| mask[u * nv + v]));
                }
            }
        }
        assert_eq!(largest(&[false; 6], 2, 3, 1), None);
    }

    #[test]
    fn a_sweep_resumed_after_cells_close_finds_what_a_new_search_finds() {
        let mut rng = fastrand::Rng::with_seed(11);
        for _ in 0..100 {
            let (nu, nv) = (rng.usize(1..12), rng.usize(1..12));
            let mut mask: Vec<bool> = (0..nu * nv).map(|_| rng.f64() < 0.8).collect();
            let mut sweep = Sweep::new(nu, nv, 2);
            let mut found = sweep.run(0..nu, &bit_rows(&mask, nu, nv), nv.div_ceil(64));
            for _ in 0..5 {
                assert_eq!(found, largest(&mask, nu, nv, 2));
                let (u, v) = (rng.usize(0..nu), rng.usize(0..nv));
                let rows = rng.usize(1..4).min(nu - u);
                for k in u..u + rows {
                    mask[k * nv + v] = false;
                }
                found = sweep.run(u..u + rows, &bit_rows(&mask, nu, nv), nv.div_ceil(64));
            }
        }
    }
}
