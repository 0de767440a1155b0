//! Exact Euclidean distance transform (Felzenszwalb & Huttenlocher 2012), separable along
//! the three axes.

use rayon::prelude::*;

const FAR: f32 = 1e20;

/// For every voxel in `set`, the squared distance in voxels to the nearest voxel outside it;
/// 0 outside. `dims` is the grid's, with z fastest.
pub fn squared_distance_to_outside(set: &[bool], dims: [usize; 3]) -> Vec<f32> {
    let [_, ny, nz] = dims;
    let mut d: Vec<f32> = set.par_iter().map(|&s| if s { FAR } else { 0.0 }).collect();
    // z: contiguous columns.
    d.par_chunks_mut(nz)
        .for_each_init(Lines::default, |lines, column| lines.transform(column));
    // y: within each x slab, across its rows.
    d.par_chunks_mut(ny * nz).for_each_init(Lines::default, |lines, slab| {
        lines.transform_across(&mut slab.chunks_mut(nz).collect::<Vec<_>>());
    });
    // x: across the rows of one y in every slab.
    let mut rows_of_y: Vec<Vec<&mut [f32]>> = (0..ny).map(|_| Vec::new()).collect();
    for slab in d.chunks_mut(ny * nz) {
        for (rows, row) in rows_of_y.iter_mut().zip(slab.chunks_mut(nz)) {
            rows.push(row);
        }
    }
    rows_of_y
        .par_iter_mut()
        .for_each_init(Lines::default, |lines, rows| lines.transform_across(rows));
    d
}

/// One thread's buffers for 1-D transforms, kept from line to line.
#[derive(Default)]
struct Lines {
    /// The lines across a set of rows, one after another.
    across: Vec<f32>,
    source: Vec<f32>,
    roots: Vec<usize>,
    bounds: Vec<f32>,
}

impl Lines {
    /// Transforms each line that takes one value from every row (rows of equal length).
    fn transform_across(&mut self, rows: &mut [&mut [f32]]) {
        let (count, length) = (rows.len(), rows.first().map_or(0, |r| r.len()));
        let mut across = std::mem::take(&mut self.across);
        across.resize(count * length, 0.0);
        for (i, row) in rows.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                across[j * count + i] = v;
            }
        }
        for line in across.chunks_mut(count.max(1)) {
            self.transform(line);
        }
        for (i, row) in rows.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = across[j * count + i];
            }
        }
        self.across = across;
    }

    /// 1-D squared distance transform of sampled function `f`, in place.
    fn transform(&mut self, f: &mut [f32]) {
        // A line wholly outside stays 0, as the parabolas would leave it: many lines of a grid
        // around a mesh miss it.
        if f.iter().all(|&x| x == 0.0) {
            return;
        }
        let n = f.len();
        // Every entry read below is written first, so old contents may stay.
        self.roots.resize(n, 0);
        self.bounds.resize(n + 1, 0.0);
        self.source.clear();
        self.source.extend_from_slice(f);
        let (v, z, src) = (&mut self.roots, &mut self.bounds, &self.source);
        let mut k = 0usize;
        let Some(first) = src.iter().position(|&x| x < FAR) else {
            return;
        };
        v[0] = first;
        z[0] = f32::NEG_INFINITY;
        z[1] = f32::INFINITY;
        for q in first + 1..n {
            if src[q] >= FAR {
                continue;
            }
            // z[0] is -inf, so k never drops below 0.
            let mut s = intersection(src, v[k], q);
            while s <= z[k] {
                k -= 1;
                s = intersection(src, v[k], q);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f32::INFINITY;
        }
        let mut j = 0;
        for (q, out) in f.iter_mut().enumerate() {
            while z[j + 1] < q as f32 {
                j += 1;
            }
            let p = v[j];
            let dq = q as f32 - p as f32;
            *out = dq * dq + src[p];
        }
    }
}

/// Where the parabolas rooted at p and q meet.
fn intersection(f: &[f32], p: usize, q: usize) -> f32 {
    let (pf, qf) = (p as f32, q as f32);
    ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_are_those_to_the_nearest_voxel_outside() {
        let dims = [9, 7, 11];
        let [nx, ny, nz] = dims;
        // A fixed scatter of outside voxels in a mostly inside grid, with a slab of x and a
        // column of z wholly outside, whose lines the transform skips.
        let set: Vec<bool> = (0..nx * ny * nz)
            .map(|i| (i * 7919) % 23 != 0 && i / (ny * nz) != 4 && i / nz != 2 * ny + 3)
            .collect();
        let at = |i: usize| [i / (ny * nz), i / nz % ny, i % nz].map(|c| c as f32);
        let got = squared_distance_to_outside(&set, dims);
        for (i, &inside) in set.iter().enumerate() {
            let p = at(i);
            let nearest = (0..set.len())
                .filter(|&o| !set[o])
                .map(|o| {
                    let q = at(o);
                    (0..3).map(|k| (p[k] - q[k]) * (p[k] - q[k])).sum::<f32>()
                })
                .fold(f32::INFINITY, f32::min);
            assert_eq!(got[i], if inside { nearest } else { 0.0 }, "voxel {i}");
        }
    }
}
