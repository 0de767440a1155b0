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
    let mut distance = squared_distance_to_outside(inner, dims);
    while free.placed.len() < settings.max_boxes && (claimed as f64) < settings.target_coverage * total as f64 {
        // The order is total (ties go to the lower index), so the parallel search is deterministic.
        let Some((seed, _)) = distance
            .par_iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
        else {
            break;
        };
        let b = grow(&free, coords(seed, dims));
        if (b.voxels() as f64) < settings.min_box_gain * total as f64 || b.voxels() < settings.min_box_voxels {
            break;
        }
        lower_to_box(&mut distance, dims, &b);
        claimed += b.voxels();
        free.placed.push(b);
    }
    free.placed
}

/// distance = min(distance, squared voxel distance to the nearest voxel of `b`).
fn lower_to_box(distance: &mut [f32], dims: [usize; 3], b: &VoxelBox) {
    let gap = |v: usize, k: usize| {
        let below = b.lo[k].saturating_sub(v);
        let above = v.saturating_sub(b.hi[k] - 1);
        (below + above) as f32
    };
    distance.par_chunks_mut(dims[2]).enumerate().for_each(|(c, column)| {
        let (gx, gy) = (gap(c / dims[1], 0), gap(c % dims[1], 1));
        let base = gx * gx + gy * gy;
        for (z, d) in column.iter_mut().enumerate() {
            let gz = gap(z, 2);
            *d = d.min(base + gz * gz);
        }
    });
}

fn coords(index: usize, dims: [usize; 3]) -> [usize; 3] {
    let z = index % dims[2];
    let xy = index / dims[2];
    [xy / dims[1], xy % dims[1], z]
}

/// Counts of a set's voxels over any box in O(1).
struct SummedVolume {
    sums: Vec<u32>,
    dims: [usize; 3],
}

impl SummedVolume {
    fn new(set: &[bool], dims: [usize; 3]) -> Self {
        let [sx, sy, sz] = dims.map(|d| d + 1);
        let mut sums = vec![0u32; sx * sy * sz];
        let at = |x: usize, y: usize, z: usize| (x * sy + y) * sz + z;
        for x in 1..sx {
            for y in 1..sy {
                for z in 1..sz {
                    let v = u32::from(set[((x - 1) * dims[1] + y - 1) * dims[2] + z - 1]);
                    sums[at(x, y, z)] = v + sums[at(x - 1, y, z)] + sums[at(x, y - 1, z)] + sums[at(x, y, z - 1)]
                        - sums[at(x - 1, y - 1, z)]
                        - sums[at(x - 1, y, z - 1)]
                        - sums[at(x, y - 1, z - 1)]
                        + sums[at(x - 1, y - 1, z - 1)];
                }
            }
        }
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
