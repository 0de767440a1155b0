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
    // heights[v]: how many rows up to the current one are true in column v.
    let mut heights = vec![0usize; nv];
    let mut best: Option<CellRect> = None;
    let mut stack: Vec<usize> = Vec::with_capacity(nv + 1);
    for u in 0..nu {
        for v in 0..nv {
            heights[v] = if mask[u * nv + v] { heights[v] + 1 } else { 0 };
        }
        stack.clear();
        for v in 0..=nv {
            let h = if v < nv { heights[v] } else { 0 };
            while let Some(&top) = stack.last() {
                if heights[top] <= h {
                    break;
                }
                stack.pop();
                let left = stack.last().map_or(0, |&s| s + 1);
                let rect = CellRect {
                    u: [u + 1 - heights[top], u + 1],
                    v: [left, v],
                };
                // Every rectangle lies in one of these maximal ones, with sides at least as long.
                let wide_enough = heights[top] >= min_side && v - left >= min_side;
                if wide_enough && best.is_none_or(|b| rect.cells() > b.cells()) {
                    best = Some(rect);
                }
            }
            stack.push(v);
        }
    }
    best
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
}
