//! Host plumbing the voxel shaders share (shaders/common.wgsl): grids larger than one storage
//! binding are processed in slabs of x layers, and meshes with more triangles than one binding
//! holds in chunks, so the adapter's limits bound memory, not what can be cooked. Work is split
//! into items small enough that no invocation loops more than llvmpipe allows (65535
//! iterations; past that it silently stops). Each stage's own host code sits beside its twin:
//! `surface/gpu.rs`, `parity/gpu.rs`, `winding/gpu.rs`.

use super::Grid;
use super::surface::SLACK;
use crate::gpu::{Gpu, GpuError, WORKGROUP, units_per_item};
use crate::mesh::Mesh;
use rayon::prelude::*;
use std::ops::Range;

/// A voxel stage's shader: shaders/common.wgsl followed by `shaders/<file>`.
macro_rules! voxel_shader {
    ($file:literal) => {
        concat!(
            include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/shaders/common.wgsl")),
            include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/shaders/", $file))
        )
    };
}
pub(super) use voxel_shader;

/// Bytes of one triangle's corners on the GPU.
const TRIANGLE_BYTES: u64 = 36;
/// Loop iterations one invocation may spend, with a margin under llvmpipe's 65535.
pub(super) const LOOP_BUDGET: usize = 50_000;

/// `Params` in shaders/common.wgsl.
pub(super) fn params(
    grid: &Grid,
    slab: &Range<usize>,
    items: usize,
    boundary_edges: usize,
    segment: usize,
) -> [u32; 9] {
    let [nx, ny, nz] = grid.dims.map(|d| d as u32);
    [
        nx,
        ny,
        nz,
        slab.start as u32,
        slab.end as u32,
        items as u32,
        boundary_edges as u32,
        (0.5 + SLACK).to_bits(),
        segment as u32,
    ]
}

/// Ranges of x layers whose output, `layer_bytes` each, fits one binding.
pub(super) fn slabs(gpu: &Gpu, grid: &Grid, layer_bytes: u64) -> Result<Vec<Range<usize>>, GpuError> {
    let per_slab = (gpu.max_binding / layer_bytes.max(1)) as usize;
    if per_slab == 0 {
        return Err(GpuError::OutOfMemory(format!(
            "one layer of the grid ({layer_bytes} bytes) exceeds the adapter's largest storage binding ({} bytes)",
            gpu.max_binding
        )));
    }
    let nx = grid.dims[0];
    Ok((0..nx).step_by(per_slab).map(|x| x..(x + per_slab).min(nx)).collect())
}

/// What a triangle pass walks over each triangle's bounds.
#[derive(Clone, Copy)]
pub(super) enum Units {
    /// Voxels, each one loop iteration.
    Voxels,
    /// Columns, each up to a column's words of bit flips.
    Columns,
}

/// A chunk of triangles on the device, their corners in voxel units.
pub(super) struct Chunk {
    triangles: Vec<[[f32; 3]; 3]>,
    buffer: wgpu::Buffer,
}

pub(super) fn triangle_chunks(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<Chunk>, GpuError> {
    let triangles = grid.local_triangles(mesh);
    let per_chunk = (gpu.max_binding / TRIANGLE_BYTES) as usize;
    if per_chunk == 0 {
        return Err(GpuError::OutOfMemory(format!(
            "one triangle exceeds the adapter's largest storage binding ({} bytes)",
            gpu.max_binding
        )));
    }
    Ok(triangles
        .chunks(per_chunk)
        .map(|c| Chunk {
            triangles: c.to_vec(),
            buffer: gpu.upload(c),
        })
        .collect())
}

/// Voxel tests one work item makes at least: a large triangle's voxels spread over many
/// threads, which a hardware GPU runs at once (on an H200 a three-storey building's surface at
/// 256³ took 21.0 ms of device time in items of 50,000 voxels, 0.2 ms in items of 256).
const ITEM_TESTS: usize = 256;

/// The work items of one chunk's `triangles` over one slab: (triangle, first unit, end unit, 0),
/// numbered as `slab_bounds` in common.wgsl does, each within the loop budget: items grow
/// towards it rather than number more than [`MAX_ITEMS`](crate::gpu::MAX_ITEMS).
fn work_items(triangles: &[[[f32; 3]; 3]], grid: &Grid, slab: &Range<usize>, units: Units) -> Vec<[u32; 4]> {
    // Loop iterations a unit costs.
    let unit_cost = match units {
        Units::Voxels => 1,
        Units::Columns => grid.dims[2].div_ceil(32) + 2,
    };
    let counts: Vec<usize> = triangles
        .iter()
        .map(|tri| {
            let [xs, ys, zs] = Grid::local_spans(tri, grid.dims);
            let x = xs.start.max(slab.start)..xs.end.min(slab.end);
            x.len()
                * ys.len()
                * match units {
                    Units::Voxels => zs.len(),
                    Units::Columns => 1,
                }
        })
        .collect();
    let units_in_all: usize = counts.iter().sum();
    let per_item = units_per_item(units_in_all, [ITEM_TESTS / unit_cost, LOOP_BUDGET / unit_cost]);
    let mut items = Vec::with_capacity(counts.len());
    for (t, count) in counts.into_iter().enumerate() {
        for first in (0..count).step_by(per_item) {
            items.push([t as u32, first as u32, (first + per_item).min(count) as u32, 0]);
        }
    }
    items
}

/// Runs a triangle pass of `entry` over every chunk for one slab; `output` is bound at 2.
pub(super) fn triangle_pass(
    gpu: &Gpu,
    (source, entry): (&'static str, &'static str),
    chunks: &[Chunk],
    grid: &Grid,
    slab: &Range<usize>,
    units: Units,
    output: &wgpu::Buffer,
) {
    for chunk in chunks {
        let items = work_items(&chunk.triangles, grid, slab, units);
        let p = gpu.upload(&params(grid, slab, items.len(), 0, 0));
        let item_buffer = gpu.upload(&items);
        let groups = (items.len() as u32).div_ceil(WORKGROUP);
        gpu.dispatch(
            source,
            entry,
            &[(0, &p), (1, &chunk.buffer), (2, output), (4, &item_buffer)],
            groups,
        );
    }
}

/// Bit i of `words` (bit i % 32 of word i / 32) into `voxels[i]`, in parallel: at 256³ that is
/// 16.7 M voxels.
pub(super) fn unpack_bits(words: &[u32], voxels: &mut [bool]) {
    voxels
        .par_chunks_mut(32)
        .zip(words)
        .with_min_len(1024)
        .for_each(|(voxels, &word)| {
            for (bit, v) in voxels.iter_mut().enumerate() {
                *v = word >> bit & 1 == 1;
            }
        });
}

/// Runs a one-bit-per-voxel stage (`surface` or `parity`) over every slab.
pub(super) fn bit_stage(
    gpu: &Gpu,
    stage: (&'static str, &'static str),
    units: Units,
    mesh: &Mesh,
    grid: &Grid,
) -> Result<Vec<bool>, GpuError> {
    gpu.run(|gpu| {
        let [_, ny, nz] = grid.dims;
        let layer = ny * nz;
        let chunks = triangle_chunks(gpu, mesh, grid)?;
        let mut voxels = vec![false; grid.len()];
        for slab in slabs(gpu, grid, (layer as u64).div_ceil(8))? {
            let count = slab.len() * layer;
            let bits = gpu.zeroed((count as u64).div_ceil(32) * 4);
            triangle_pass(gpu, stage, &chunks, grid, &slab, units, &bits);
            unpack_bits(&gpu.read(&bits)?, &mut voxels[slab.start * layer..slab.end * layer]);
        }
        Ok(voxels)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::MAX_ITEMS;
    use glam::Vec3;

    /// Items of `n` triangles, each across the whole of a `side`³ grid, over its one slab, and
    /// the voxels each triangle's bounds meet.
    fn items(n: usize, side: usize, units: Units) -> (Vec<[u32; 4]>, usize) {
        let grid = Grid::fit(Vec3::ZERO, Vec3::ONE, side);
        let s = side as f32;
        let across = [[0.0, 0.0, 0.0], [s, s, 0.0], [s, s, s]];
        let voxels = Grid::local_spans(&across, grid.dims).iter().map(|r| r.len()).product();
        (work_items(&vec![across; n], &grid, &(0..grid.dims[0]), units), voxels)
    }

    #[test]
    fn a_large_triangles_voxels_spread_over_small_items_that_cover_them_once() {
        let (found, voxels) = items(1, 64, Units::Voxels);
        assert!(voxels >= 64usize.pow(3));
        assert_eq!(found.len(), voxels.div_ceil(ITEM_TESTS));
        assert!(found.iter().all(|&[_, first, end, _]| end - first <= ITEM_TESTS as u32));
        assert!(found.windows(2).all(|w| w[0][2] == w[1][1]));
        assert_eq!(found.last().map(|i| i[2] as usize), Some(voxels));
        // A column costs a loop a word of it, and two more.
        let (columns, _) = items(1, 64, Units::Columns);
        assert!(
            columns
                .iter()
                .all(|&[_, first, end, _]| end - first <= (ITEM_TESTS / 4) as u32)
        );
    }

    #[test]
    fn many_large_triangles_grow_their_items_rather_than_the_list() {
        // 300 triangles across a 160³ grid: 1.2 billion voxel tests.
        let (found, _) = items(300, 160, Units::Voxels);
        assert!(found.len() <= MAX_ITEMS + 300, "{} items", found.len());
        assert!(
            found
                .iter()
                .all(|&[_, first, end, _]| end - first <= LOOP_BUDGET as u32)
        );
    }
}
