//! The voxel stages on the GPU: host code for shaders/surface.wgsl, parity.wgsl and
//! winding.wgsl. Their CPU twins are the modules of the same names in `crate::voxel`.
//!
//! Grids larger than one storage binding are processed in slabs of x layers, and meshes with
//! more triangles than one binding holds in chunks, so the adapter's limits bound memory, not
//! what can be cooked.

use super::{Gpu, GpuError};
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
pub const ENTRY_POINTS: [(&str, &str); 4] = [
    (SURFACE, "surface"),
    (PARITY, "parity"),
    (WINDING, "crossings"),
    (WINDING, "classify"),
];

/// Bytes of one triangle's corners on the GPU.
const TRIANGLE_BYTES: u64 = 36;
/// Threads in a workgroup, as the shaders declare.
const WORKGROUP: u32 = 64;

/// `Params` in shaders/common.wgsl.
fn params(grid: &Grid, slab: &Range<usize>, triangles: usize, boundary_edges: usize) -> [u32; 8] {
    let [nx, ny, nz] = grid.dims.map(|d| d as u32);
    [
        nx,
        ny,
        nz,
        slab.start as u32,
        slab.end as u32,
        triangles as u32,
        boundary_edges as u32,
        (0.5 + SLACK).to_bits(),
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

/// The mesh's corners in voxel units, as buffers of at most one binding each, with their
/// triangle counts.
fn triangle_chunks(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Vec<(wgpu::Buffer, usize)> {
    let corners = grid.local_corners(mesh);
    let per_chunk = (gpu.max_binding / TRIANGLE_BYTES) as usize;
    corners
        .chunks(per_chunk * 9)
        .map(|c| (gpu.upload(c), c.len() / 9))
        .collect()
}

/// Runs a one-bit-per-voxel stage (`surface` or `parity`): every triangle chunk over every slab.
fn bit_stage(
    gpu: &Gpu,
    source: &'static str,
    entry: &'static str,
    mesh: &Mesh,
    grid: &Grid,
) -> Result<Vec<bool>, GpuError> {
    gpu.run(|gpu| {
        let [_, ny, nz] = grid.dims;
        let layer = ny * nz;
        let chunks = triangle_chunks(gpu, mesh, grid);
        let mut voxels = vec![false; grid.len()];
        for slab in slabs(gpu, grid, (layer as u64).div_ceil(8))? {
            let count = slab.len() * layer;
            let bits = gpu.zeroed((count as u64).div_ceil(32) * 4);
            for (corners, triangles) in &chunks {
                let p = gpu.upload(&params(grid, &slab, *triangles, 0));
                let groups = (*triangles as u32).div_ceil(WORKGROUP);
                gpu.dispatch(source, entry, &[(0, &p), (1, corners), (2, &bits)], groups);
            }
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
    bit_stage(gpu, SURFACE, "surface", mesh, grid)
}

/// Twin of [`crate::voxel::parity::classify`].
pub fn parity(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<bool>, GpuError> {
    bit_stage(gpu, PARITY, "parity", mesh, grid)
}

/// Twin of [`crate::voxel::winding::classify`].
pub fn winding(gpu: &Gpu, mesh: &Mesh, boundary: &[BoundaryEdge], grid: &Grid) -> Result<Vec<bool>, GpuError> {
    gpu.run(|gpu| {
        let [_, ny, nz] = grid.dims;
        let layer = ny * nz;
        let chunks = triangle_chunks(gpu, mesh, grid);
        let edges: Vec<f32> = boundary
            .iter()
            .flat_map(|e| {
                let [a, b] = [e.a, e.b].map(|v| grid.local(mesh.positions[v as usize].as_dvec3()));
                [a[0], a[1], a[2], b[0], b[1], b[2], e.weight as f32, 0.0]
            })
            .collect();
        let edges = gpu.upload(&edges);
        let mut voxels = vec![false; grid.len()];
        for slab in slabs(gpu, grid, layer as u64 * 4)? {
            let count = slab.len() * layer;
            let sums = gpu.zeroed(count as u64 * 4);
            for (corners, triangles) in &chunks {
                let p = gpu.upload(&params(grid, &slab, *triangles, 0));
                gpu.dispatch(
                    WINDING,
                    "crossings",
                    &[(0, &p), (1, corners), (2, &sums)],
                    *triangles as u32,
                );
            }
            let p = gpu.upload(&params(grid, &slab, 0, boundary.len()));
            let columns = (slab.len() * ny) as u32;
            gpu.dispatch(
                WINDING,
                "classify",
                &[(0, &p), (2, &sums), (3, &edges)],
                columns.div_ceil(WORKGROUP),
            );
            let inside: Vec<i32> = gpu.read(&sums)?;
            for (v, &flag) in voxels[slab.start * layer..slab.end * layer].iter_mut().zip(&inside) {
                *v = flag == 1;
            }
        }
        Ok(voxels)
    })
}
