//! Exact Euclidean distance transform (Felzenszwalb & Huttenlocher 2012), separable along
//! the three axes.

use rayon::prelude::*;

const FAR: f32 = 1e20;

/// For every voxel in `set`, the squared distance in voxels to the nearest voxel outside it;
/// 0 outside. `dims` is the grid's, with z fastest.
pub fn squared_distance_to_outside(set: &[bool], dims: [usize; 3]) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let mut d: Vec<f32> = set.iter().map(|&s| if s { FAR } else { 0.0 }).collect();
    // z: contiguous columns.
    d.par_chunks_mut(nz).for_each(transform_line);
    // y and x: gather each line, transform, scatter back.
    for (axis_len, stride, count) in [(ny, nz, nx * nz), (nx, ny * nz, ny * nz)] {
        let lines: Vec<Vec<f32>> = (0..count)
            .into_par_iter()
            .map(|l| {
                let base = line_base(l, axis_len, stride, dims);
                let mut line: Vec<f32> = (0..axis_len).map(|i| d[base + i * stride]).collect();
                transform_line(&mut line);
                line
            })
            .collect();
        for (l, line) in lines.iter().enumerate() {
            let base = line_base(l, axis_len, stride, dims);
            for (i, v) in line.iter().enumerate() {
                d[base + i * stride] = *v;
            }
        }
    }
    d
}

/// The flat index of the first voxel of line `l` along the axis with the given stride.
fn line_base(l: usize, axis_len: usize, stride: usize, dims: [usize; 3]) -> usize {
    let nz = dims[2];
    if stride == nz {
        // along y: l enumerates (x, z)
        let (x, z) = (l / nz, l % nz);
        x * axis_len * nz + z
    } else {
        // along x: l enumerates (y, z), which is the offset itself
        l
    }
}

/// 1-D squared distance transform of sampled function `f`, in place.
fn transform_line(f: &mut [f32]) {
    let n = f.len();
    let mut v = vec![0usize; n];
    let mut z = vec![0f32; n + 1];
    let mut k = 0usize;
    let src = f.to_vec();
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
        let mut s = intersection(&src, v[k], q);
        while s <= z[k] {
            k -= 1;
            s = intersection(&src, v[k], q);
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

/// Where the parabolas rooted at p and q meet.
fn intersection(f: &[f32], p: usize, q: usize) -> f32 {
    let (pf, qf) = (p as f32, q as f32);
    ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
}
