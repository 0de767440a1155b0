//! Host code for shaders/winding.wgsl; the twin is [`super::classify`].

use super::STRIDE;
use crate::gpu::{Gpu, GpuError, WORKGROUP};
use crate::mesh::{BoundaryEdge, Mesh};
use crate::voxel::Grid;
use crate::voxel::gpu::{LOOP_BUDGET, Units, params, slabs, triangle_chunks, triangle_pass, unpack_bits, voxel_shader};

const SHADER: &str = voxel_shader!("winding.wgsl");

/// Built when a cook opens the device, like the surface stage's.
pub const ENTRY_POINTS: [(&str, &str); 3] = [(SHADER, "crossings"), (SHADER, "above"), (SHADER, "classify")];

/// Boundary edges the winding shader reads from its uniform buffer (`UNIFORM_EDGES` in
/// winding.wgsl); the rest come from storage.
const UNIFORM_EDGES: usize = 2048;

/// Voxels of a column per `classify` thread: a multiple of the sample spacing for which even
/// evaluating the curtain exactly at every voxel stays in the loop budget. None when not even
/// one spacing does (too many boundary edges for this design).
pub fn winding_segment(boundary_edges: usize) -> Option<usize> {
    let per_voxel = boundary_edges + 2;
    // A run of n voxels has n + n / STRIDE + 1 curtain evaluations at most.
    let runs = (LOOP_BUDGET / per_voxel).saturating_sub(1) * STRIDE / (STRIDE + 1) / STRIDE;
    (runs > 0).then_some(runs * STRIDE)
}

/// Twin of [`super::classify`]. Fails with [`GpuError::Unsupported`] when the
/// mesh has more boundary edges than one invocation can sum.
pub fn classify(gpu: &Gpu, mesh: &Mesh, boundary: &[BoundaryEdge], grid: &Grid) -> Result<Vec<bool>, GpuError> {
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
        // Signed sums: 4 bytes a voxel; the inside bits are a 32nd of that.
        for slab in slabs(gpu, grid, layer as u64 * 4)? {
            let count = slab.len() * layer;
            let sums = gpu.zeroed(count as u64 * 4);
            let inside = gpu.zeroed((count as u64).div_ceil(32) * 4);
            triangle_pass(gpu, (SHADER, "crossings"), &chunks, grid, &slab, Units::Columns, &sums);
            let columns = slab.len() * ny;
            let p = gpu.upload(&params(grid, &slab, 0, boundary.len(), segment));
            let groups = |threads: usize| (threads as u32).div_ceil(WORKGROUP);
            gpu.dispatch(SHADER, "above", &[(0, &p), (2, &sums)], groups(columns));
            let segments = (nz - 1).div_ceil(segment).max(1);
            gpu.dispatch(
                SHADER,
                "classify",
                &[(0, &p), (2, &sums), (3, &edges), (5, &inside), (6, &more_edges)],
                groups(columns * segments),
            );
            unpack_bits(&gpu.read(&inside)?, &mut voxels[slab.start * layer..slab.end * layer]);
        }
        Ok(voxels)
    })
}
