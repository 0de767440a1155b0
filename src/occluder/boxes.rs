//! Box expansion over the inner voxels: seed at the free voxel farthest from everything that is
//! not free, grow the box face by face while the grown slab stays free, claim it, repeat.
//!
//! Growth is not uniform: several growth orders run from each seed and the largest box wins,
//! because the first box placed in a region decides what is left for the others.

use super::distance::squared_distance_to_outside;
use rayon::prelude::*;
use serde::Serialize;

/// A box of voxels, `lo` inclusive, `hi` exclusive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct VoxelBox {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

impl VoxelBox {
    pub fn voxels(&self) -> usize {
        (0..3).map(|k| self.hi[k] - self.lo[k]).product()
    }

    fn overlaps(&self, other: &VoxelBox) -> bool {
        (0..3).all(|k| self.lo[k] < other.hi[k] && other.lo[k] < self.hi[k])
    }
}

pub struct ExpansionSettings {
    pub target_coverage: f64,
    pub min_box_gain: f64,
    pub max_boxes: usize,
    pub min_box_voxels: usize,
}

/// Boxes that fill `inner` without overlapping, largest first.
pub fn expand(inner: &[bool], dims: [usize; 3], settings: &ExpansionSettings) -> Vec<VoxelBox> {
    let total = inner.iter().filter(|&&v| v).count();
    let mut free = FreeSpace {
        inner: SummedVolume::new(inner, dims),
        placed: Vec::new(),
    };
    let mut claimed = 0usize;
    // Claiming a box only brings the outside nearer, so the distance field is updated with the
    // distance to each new box rather than recomputed.
    let mut distance = Farthest::new(squared_distance_to_outside(inner, dims), dims);
    while free.placed.len() < settings.max_boxes && (claimed as f64) < settings.target_coverage * total as f64 {
        let Some(seed) = distance.farthest() else {
            break;
        };
        let b = grow(&free, coords(seed, dims));
        if (b.voxels() as f64) < settings.min_box_gain * total as f64 || b.voxels() < settings.min_box_voxels {
            break;
        }
        distance.lower_to_box(&b);
        claimed += b.voxels();
        free.placed.push(b);
    }
    free.placed
}

/// The squared distance field, with each column's (x, y) largest value, so that the farthest
/// voxel is found among the columns and a box lowers only the columns it comes nearer to than
/// their largest value.
struct Farthest {
    distance: Vec<f32>,
    column_max: Vec<f32>,
    dims: [usize; 3],
}

impl Farthest {
    fn new(distance: Vec<f32>, dims: [usize; 3]) -> Farthest {
        let column_max = distance.par_chunks(dims[2]).map(largest).collect();
        Farthest {
            distance,
            column_max,
            dims,
        }
    }

    /// The voxel with the largest nonzero distance; ties go to the lower index, so the choice
    /// does not depend on how the work is split.
    fn farthest(&self) -> Option<usize> {
        let (column, &max) = self
            .column_max
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))?;
        if max <= 0.0 {
            return None;
        }
        let nz = self.dims[2];
        let z = self.distance[column * nz..(column + 1) * nz]
            .iter()
            .position(|&d| d == max)?;
        Some(column * nz + z)
    }

    /// distance = min(distance, squared voxel distance to the nearest voxel of `b`). A column
    /// no nearer to `b` than its largest value keeps every value.
    fn lower_to_box(&mut self, b: &VoxelBox) {
        let dims = self.dims;
        let gap = |v: usize, k: usize| {
            let below = b.lo[k].saturating_sub(v);
            let above = v.saturating_sub(b.hi[k] - 1);
            (below + above) as f32
        };
        self.distance
            .par_chunks_mut(dims[2])
            .zip(self.column_max.par_iter_mut())
            .enumerate()
            .for_each(|(c, (column, max))| {
                let (gx, gy) = (gap(c / dims[1], 0), gap(c % dims[1], 1));
                let base = gx * gx + gy * gy;
                if *max <= base {
                    return;
                }
                for (z, d) in column.iter_mut().enumerate() {
                    let gz = gap(z, 2);
                    *d = d.min(base + gz * gz);
                }
                *max = largest(column);
            });
    }
}

fn largest(column: &[f32]) -> f32 {
    column.iter().copied().fold(0.0, f32::max)
}

fn coords(index: usize, dims: [usize; 3]) -> [usize; 3] {
    let z = index % dims[2];
    let xy = index / dims[2];
    [xy / dims[1], xy % dims[1], z]
}

/// Entries of a slab summed along x by one task.
const SUM_SHARE: usize = 4096;

/// Counts of a set's voxels over any box in O(1).
struct SummedVolume {
    sums: Vec<u32>,
    dims: [usize; 3],
}

impl SummedVolume {
    fn new(set: &[bool], dims: [usize; 3]) -> Self {
        let [sx, sy, sz] = dims.map(|d| d + 1);
        let mut sums = vec![0u32; sx * sy * sz];
        // Running sums along z, then y, then x: integers, so the same counts as summing each
        // box, and each slab of x is summed along z and y on its own.
        sums.par_chunks_mut(sy * sz).skip(1).enumerate().for_each(|(x, slab)| {
            for y in 1..sy {
                let voxels = &set[(x * dims[1] + y - 1) * dims[2]..][..dims[2]];
                let (above, row) = slab.split_at_mut(y * sz);
                let (above, row) = (&above[(y - 1) * sz..], &mut row[..sz]);
                for z in 1..sz {
                    row[z] = row[z - 1] + u32::from(voxels[z - 1]);
                }
                for (r, a) in row.iter_mut().zip(above) {
                    *r += a;
                }
            }
        });
        // Then along x: a share of each slab's entries at a time, through every slab in turn.
        let entries = sy * sz;
        let mut shares: Vec<Vec<&mut [u32]>> = (0..entries.div_ceil(SUM_SHARE))
            .map(|_| Vec::with_capacity(sx))
            .collect();
        for slab in sums.chunks_mut(entries) {
            for (share, part) in shares.iter_mut().zip(slab.chunks_mut(SUM_SHARE)) {
                share.push(part);
            }
        }
        shares.par_iter_mut().for_each(|parts| {
            for x in 1..parts.len() {
                let (before, after) = parts.split_at_mut(x);
                after[0].iter_mut().zip(&*before[x - 1]).for_each(|(s, p)| *s += p);
            }
        });
        SummedVolume { sums, dims }
    }

    fn count(&self, b: &VoxelBox) -> usize {
        let [sy, sz] = [self.dims[1] + 1, self.dims[2] + 1];
        let s = |x: usize, y: usize, z: usize| i64::from(self.sums[(x * sy + y) * sz + z]);
        let ([x0, y0, z0], [x1, y1, z1]) = (b.lo, b.hi);
        (s(x1, y1, z1) - s(x0, y1, z1) - s(x1, y0, z1) - s(x1, y1, z0) + s(x0, y0, z1) + s(x0, y1, z0) + s(x1, y0, z0)
            - s(x0, y0, z0)) as usize
    }

    fn is_free(&self, b: &VoxelBox) -> bool {
        self.count(b) == b.voxels()
    }
}

/// The inner voxels not yet claimed: the inner set's summed volume less the placed boxes, which
/// are few, so claiming a box costs nothing and nothing is rebuilt.
struct FreeSpace {
    inner: SummedVolume,
    placed: Vec<VoxelBox>,
}

impl FreeSpace {
    fn is_free(&self, b: &VoxelBox) -> bool {
        self.inner.is_free(b) && !self.placed.iter().any(|p| p.overlaps(b))
    }

    /// The box grown by one layer on face (axis, positive side), if that layer is free.
    fn grown(&self, b: &VoxelBox, axis: usize, positive: bool) -> Option<VoxelBox> {
        let mut slab = *b;
        let mut out = *b;
        if positive {
            if b.hi[axis] >= self.inner.dims[axis] {
                return None;
            }
            slab.lo[axis] = b.hi[axis];
            slab.hi[axis] = b.hi[axis] + 1;
            out.hi[axis] += 1;
        } else {
            if b.lo[axis] == 0 {
                return None;
            }
            slab.lo[axis] = b.lo[axis] - 1;
            slab.hi[axis] = b.lo[axis];
            out.lo[axis] -= 1;
        }
        self.is_free(&slab).then_some(out)
    }
}

const FACES: [(usize, bool); 6] = [(0, false), (0, true), (1, false), (1, true), (2, false), (2, true)];

/// The largest of the boxes that several growth orders reach from `seed`.
fn grow(free: &FreeSpace, seed: [usize; 3]) -> VoxelBox {
    let start = VoxelBox {
        lo: seed,
        hi: seed.map(|s| s + 1),
    };
    let mut candidates = vec![grow_largest_slab_first(free, start), grow_round_robin(free, start)];
    for order in [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]] {
        candidates.push(grow_axis_order(free, start, order));
    }
    // Stable choice on ties: the first candidate wins.
    candidates
        .into_iter()
        .rev()
        .max_by_key(|b| b.voxels())
        .expect("candidates are never empty")
}

/// Each step takes the face whose free slab is largest.
fn grow_largest_slab_first(free: &FreeSpace, mut b: VoxelBox) -> VoxelBox {
    while let Some(next) = FACES
        .iter()
        .filter_map(|&(axis, positive)| free.grown(&b, axis, positive))
        .max_by_key(|n| n.voxels())
    {
        b = next;
    }
    b
}

/// The uniform growth of the article: every face one layer per round.
fn grow_round_robin(free: &FreeSpace, mut b: VoxelBox) -> VoxelBox {
    loop {
        let mut grew = false;
        for &(axis, positive) in &FACES {
            if let Some(next) = free.grown(&b, axis, positive) {
                b = next;
                grew = true;
            }
        }
        if !grew {
            return b;
        }
    }
}

/// Grow fully along the first axis (both sides alternately), then the second, then the third,
/// and repeat until nothing moves.
fn grow_axis_order(free: &FreeSpace, mut b: VoxelBox, order: [usize; 3]) -> VoxelBox {
    loop {
        let mut grew = false;
        for axis in order {
            loop {
                let mut step = false;
                for positive in [false, true] {
                    if let Some(next) = free.grown(&b, axis, positive) {
                        b = next;
                        step = true;
                    }
                }
                if !step {
                    break;
                }
                grew = true;
            }
        }
        if !grew {
            return b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The voxel with the largest nonzero distance, lowest index first, by looking at each.
    fn farthest_by_scan(distance: &[f32]) -> Option<usize> {
        distance
            .iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .map(|(i, _)| i)
    }

    #[test]
    fn summed_volumes_count_the_voxels_of_any_box() {
        let mut rng = fastrand::Rng::with_seed(8);
        // Slabs of 71 × 81 entries: two shares each along x.
        let dims = [6, 70, 80];
        let set: Vec<bool> = (0..dims.iter().product()).map(|_| rng.u8(..) < 90).collect();
        let volume = SummedVolume::new(&set, dims);
        for _ in 0..500 {
            let ends = |n: usize, rng: &mut fastrand::Rng| {
                let (a, b) = (rng.usize(0..=n), rng.usize(0..=n));
                (a.min(b), a.max(b))
            };
            let [(x0, x1), (y0, y1), (z0, z1)] = dims.map(|n| ends(n, &mut rng));
            let b = VoxelBox {
                lo: [x0, y0, z0],
                hi: [x1, y1, z1],
            };
            let counted = (x0..x1)
                .flat_map(|x| (y0..y1).flat_map(move |y| (z0..z1).map(move |z| (x * dims[1] + y) * dims[2] + z)))
                .filter(|&i| set[i])
                .count();
            assert_eq!(volume.count(&b), counted, "{b:?}");
        }
    }

    #[test]
    fn the_column_maxima_find_the_farthest_voxel_a_scan_finds_as_boxes_are_claimed() {
        let mut rng = fastrand::Rng::with_seed(3);
        let dims = [13, 9, 17];
        let inner: Vec<bool> = (0..dims.iter().product()).map(|_| rng.f32() < 0.9).collect();
        let mut field = Farthest::new(squared_distance_to_outside(&inner, dims), dims);
        let mut claimed = 0;
        while let Some(seed) = field.farthest() {
            assert_eq!(Some(seed), farthest_by_scan(&field.distance));
            let lo = coords(seed, dims);
            let hi: [usize; 3] = std::array::from_fn(|k| (lo[k] + 1 + rng.usize(0..3)).min(dims[k]));
            let b = VoxelBox { lo, hi };
            let mut lowered = field.distance.clone();
            for (i, d) in lowered.iter_mut().enumerate() {
                let v = coords(i, dims);
                let gap = |k: usize| (b.lo[k].saturating_sub(v[k]) + v[k].saturating_sub(b.hi[k] - 1)) as f32;
                *d = d.min(gap(0) * gap(0) + gap(1) * gap(1) + gap(2) * gap(2));
            }
            field.lower_to_box(&b);
            assert_eq!(field.distance, lowered);
            claimed += 1;
        }
        assert!(claimed > 10, "only {claimed} boxes claimed");
        assert_eq!(farthest_by_scan(&field.distance), None);
    }
}
