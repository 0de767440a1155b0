//! The voxel stages on the GPU: host code for shaders/surface.wgsl, parity.wgsl and
//! winding.wgsl. Their CPU twins are the modules of the same names in `crate::voxel`.
//!
//! Grids larger than one storage binding are processed in slabs of x layers, and meshes with
//! more triangles than one binding holds in chunks, so the adapter's limits bound memory, not
//! what can be cooked. Work is split into items small enough that no invocation loops more than
//! llvmpipe allows (65535 iterations; past that it silently stops).

use super::{Gpu, GpuError, WORKGROUP};
use crate::mesh::{BoundaryEdge, Mesh};
use crate::voxel::Grid;
use crate::voxel::surface::SLACK;
use std::ops::Range;

const SURFACE: &str = concat!(
    include_str!("../../shaders/common.wgsl"),
    include_str!("../../shaders/surface.wgsl")
);
const PARITY: &str = concat!(
    include_str!("../../shaders/common.wgsl"),
    include_str!("../../shaders/parity.wgsl")
);
const WINDING: &str = concat!(
    include_str!("../../shaders/common.wgsl"),
    include_str!("../../shaders/winding.wgsl")
);

/// Every entry point of the voxel stages, built when the device opens so that no cook pays
/// for shader compilation.
pub const ENTRY_POINTS: [(&str, &str); 5] = [
    (SURFACE, "surface"),
    (PARITY, "parity"),
    (WINDING, "crossings"),
    (WINDING, "above"),
    (WINDING, "classify"),
];

/// Bytes of one triangle's corners on the GPU.
const TRIANGLE_BYTES: u64 = 36;
/// Loop iterations one invocation may spend, with a margin under llvmpipe's 65535.
const LOOP_BUDGET: usize = 50_000;
/// Boundary edges the winding shader reads from its uniform buffer (`UNIFORM_EDGES` in
/// winding.wgsl); the rest come from storage.
const UNIFORM_EDGES: usize = 2048;
/// The CPU twin's sample spacing along a column (`STRIDE` in winding.wgsl).
const STRIDE: usize = 8;

/// `Params` in shaders/common.wgsl.
fn params(grid: &Grid, slab: &Range<usize>, items: usize, boundary_edges: usize, segment: usize) -> [u32; 9] {
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
fn slabs(gpu: &Gpu, grid: &Grid, layer_bytes: u64) -> Result<Vec<Range<usize>>, GpuError> {
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
enum Units {
    /// Voxels, each one loop iteration.
    Voxels,
    /// Columns, each up to a column's words of bit flips.
    Columns,
}

/// A chunk of triangles on the device, their corners in voxel units.
struct Chunk {
    triangles: Vec<[[f32; 3]; 3]>,
    buffer: wgpu::Buffer,
}

fn triangle_chunks(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<Chunk>, GpuError> {
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

/// The work items of one chunk over one slab: (triangle, first unit, end unit, 0), numbered as
/// `slab_bounds` in common.wgsl does, each within the loop budget.
fn work_items(chunk: &Chunk, grid: &Grid, slab: &Range<usize>, units: Units) -> Vec<[u32; 4]> {
    let per_item = match units {
        Units::Voxels => LOOP_BUDGET,
        Units::Columns => LOOP_BUDGET / (grid.dims[2].div_ceil(32) + 2),
    };
    let mut items = Vec::new();
    for (t, tri) in chunk.triangles.iter().enumerate() {
        let [xs, ys, zs] = Grid::local_spans(tri, grid.dims);
        let x = xs.start.max(slab.start)..xs.end.min(slab.end);
        let count = x.len()
            * ys.len()
            * match units {
                Units::Voxels => zs.len(),
                Units::Columns => 1,
            };
        for first in (0..count).step_by(per_item) {
            items.push([t as u32, first as u32, (first + per_item).min(count) as u32, 0]);
        }
    }
    items
}

/// Runs a triangle pass of `entry` over every chunk for one slab; `output` is bound at 2.
fn triangle_pass(
    gpu: &Gpu,
    (source, entry): (&'static str, &'static str),
    chunks: &[Chunk],
    grid: &Grid,
    slab: &Range<usize>,
    units: Units,
    output: &wgpu::Buffer,
) {
    for chunk in chunks {
        let items = work_items(chunk, grid, slab, units);
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

/// Runs a one-bit-per-voxel stage (`surface` or `parity`) over every slab.
fn bit_stage(
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
            let words: Vec<u32> = gpu.read(&bits)?;
            let out = &mut voxels[slab.start * layer..slab.end * layer];
            for (i, v) in out.iter_mut().enumerate() {
                *v = words[i / 32] >> (i % 32) & 1 == 1;
            }
        }
        Ok(voxels)
    })
}

/// Twin of [`crate::voxel::surface::voxelize`].
pub fn surface(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<bool>, GpuError> {
    bit_stage(gpu, (SURFACE, "surface"), Units::Voxels, mesh, grid)
}

/// Twin of [`crate::voxel::parity::classify`].
pub fn parity(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<bool>, GpuError> {
    bit_stage(gpu, (PARITY, "parity"), Units::Columns, mesh, grid)
}

/// Voxels of a column per `classify` thread: a multiple of the sample spacing for which even
/// evaluating the curtain exactly at every voxel stays in the loop budget. None when not even
/// one spacing does (too many boundary edges for this design).
pub fn winding_segment(boundary_edges: usize) -> Option<usize> {
    let per_voxel = boundary_edges + 2;
    // A run of n voxels has n + n / STRIDE + 1 curtain evaluations at most.
    let runs = (LOOP_BUDGET / per_voxel).saturating_sub(1) * STRIDE / (STRIDE + 1) / STRIDE;
    (runs > 0).then_some(runs * STRIDE)
}

/// Twin of [`crate::voxel::winding::classify`]. Fails with [`GpuError::Unsupported`] when the
/// mesh has more boundary edges than one invocation can sum.
pub fn winding(gpu: &Gpu, mesh: &Mesh, boundary: &[BoundaryEdge], grid: &Grid) -> Result<Vec<bool>, GpuError> {
    let segment = winding_segment(boundary.len()).ok_or_else(|| {
        GpuError::Unsupported(format!(
            "{} open boundary edges are more than one GPU thread may sum",
            boundary.len()
        ))
    })?;
    gpu.run(|gpu| {
        let [_, ny, nz] = grid.dims;
        let layer = ny * nz;
        let chunks = triangle_chunks(gpu, mesh, grid)?;
        let edges: Vec<[f32; 4]> = boundary
            .iter()
            .flat_map(|e| {
                let [a, b] = [e.a, e.b].map(|v| grid.local(mesh.positions[v as usize].as_dvec3()));
                [[a[0], a[1], a[2], e.weight as f32], [b[0], b[1], b[2], 0.0]]
            })
            .collect();
        let split = edges.len().min(2 * UNIFORM_EDGES);
        let (edges, more_edges) = (
            gpu.uniform(&edges[..split], 2 * UNIFORM_EDGES),
            gpu.upload(&edges[split..]),
        );
        let mut voxels = vec![false; grid.len()];
        // Signed sums and inside flags: 8 bytes a voxel.
        for slab in slabs(gpu, grid, layer as u64 * 4)? {
            let count = slab.len() * layer;
            let sums = gpu.zeroed(count as u64 * 4);
            let inside = gpu.zeroed(count as u64 * 4);
            triangle_pass(gpu, (WINDING, "crossings"), &chunks, grid, &slab, Units::Columns, &sums);
            let columns = slab.len() * ny;
            let p = gpu.upload(&params(grid, &slab, 0, boundary.len(), segment));
            let groups = |threads: usize| (threads as u32).div_ceil(WORKGROUP);
            gpu.dispatch(WINDING, "above", &[(0, &p), (2, &sums)], groups(columns));
            let segments = (nz - 1).div_ceil(segment).max(1);
            gpu.dispatch(
                WINDING,
                "classify",
                &[(0, &p), (2, &sums), (3, &edges), (5, &inside), (6, &more_edges)],
                groups(columns * segments),
            );
            let flags: Vec<u32> = gpu.read(&inside)?;
            for (v, &flag) in voxels[slab.start * layer..slab.end * layer].iter_mut().zip(&flags) {
                *v = flag == 1;
            }
        }
        Ok(voxels)
    })
}
