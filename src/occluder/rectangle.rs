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
    Sweep::new(nu, nv, min_side).run(0, |u, v| mask[u * nv + v])
}

/// The histogram method's pass over row `u`: the rectangles that end on it, each as tall as a
/// column's height and as wide as the columns around it at least as high, replace `best` when
/// larger (so the first found of the largest size stays).
fn pop_row(u: usize, heights: &[u32], min_side: usize, stack: &mut Vec<usize>, best: &mut Option<CellRect>) {
    let nv = heights.len();
    stack.clear();
    for v in 0..=nv {
        let h = if v < nv { heights[v] } else { 0 };
        while let Some(&top) = stack.last() {
            if heights[top] <= h {
                break;
            }
            stack.pop();
            let left = stack.last().map_or(0, |&s| s + 1);
            let height = heights[top] as usize;
            let rect = CellRect {
                u: [u + 1 - height, u + 1],
                v: [left, v],
            };
            // Every rectangle lies in one of these maximal ones, with sides at least as long.
            let wide_enough = height >= min_side && v - left >= min_side;
            if wide_enough && best.is_none_or(|b| rect.cells() > b.cells()) {
                *best = Some(rect);
            }
        }
        stack.push(v);
    }
}

/// [`largest`] kept row by row, for a mask whose cells only ever close: after cells close
/// from row `from` on, [`Sweep::run`] redoes only those rows, and finds what a new search
/// would, the same rectangle included.
pub struct Sweep {
    nv: usize,
    min_side: usize,
    /// Each row's column heights, `nv` a row.
    heights: Vec<u32>,
    /// The best rectangle ending on or before each row.
    best: Vec<Option<CellRect>>,
    stack: Vec<usize>,
}

impl Sweep {
    pub fn new(nu: usize, nv: usize, min_side: usize) -> Sweep {
        Sweep {
            nv,
            min_side,
            heights: vec![0; nu * nv],
            best: vec![None; nu],
            stack: Vec::with_capacity(nv + 1),
        }
    }

    /// The cells it sweeps.
    pub fn cells(&self) -> usize {
        self.heights.len()
    }

    /// The largest rectangle of the cells for which `open(u, v)` holds, sweeping again from
    /// row `from`: rows before it must be as the last run saw them.
    pub fn run(&mut self, from: usize, open: impl Fn(usize, usize) -> bool) -> Option<CellRect> {
        let (nv, nu) = (self.nv, self.best.len());
        for u in from..nu {
            let (done, rest) = self.heights.split_at_mut(u * nv);
            let row = &mut rest[..nv];
            // The row above; none on the first.
            let above = &done[done.len().saturating_sub(nv)..];
            for (v, h) in row.iter_mut().enumerate() {
                *h = if open(u, v) {
                    above.get(v).copied().unwrap_or(0) + 1
                } else {
                    0
                };
            }
            let mut best = if u > 0 { self.best[u - 1] } else { None };
            pop_row(u, row, self.min_side, &mut self.stack, &mut best);
            self.best[u] = best;
        }
        self.best.last().copied().flatten()
    }
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
            let mut found = sweep.run(0, |u, v| mask[u * nv + v]);
            for _ in 0..5 {
                assert_eq!(found, largest(&mask, nu, nv, 2));
                let (u, v) = (rng.usize(0..nu), rng.usize(0..nv));
                let rows = rng.usize(1..4).min(nu - u);
                for k in u..u + rows {
                    mask[k * nv + v] = false;
                }
                found = sweep.run(u, |u, v| mask[u * nv + v]);
            }
        }
    }
}
