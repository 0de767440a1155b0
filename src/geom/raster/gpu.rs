//! Host code for shaders/raster.wgsl: depth images of a mesh from orthographic views, rasterized
//! in compute, read back in one go. The twin is [`super::depth_image`].

use crate::geom::camera::View;
use crate::gpu::{Gpu, GpuError, WORKGROUP};
use crate::mesh::Mesh;
use rayon::prelude::*;

const SHADER: &str = include_str!("../../../shaders/raster.wgsl");

/// Built when a cook opens the device, like the voxel stages' entry points.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "depth_min")];

/// Pixel tests one thread may make over its views: under llvmpipe's 65535 loop iterations.
const THREAD_PIXELS: usize = 49152;
/// The shader's `nearness` key of an empty pixel.
const EMPTY: u32 = 0;
/// The most views one dispatch draws: the shader's uniform array holds three rows each.
const MAX_VIEWS: usize = 256;

/// The nearest depth per pixel of `mesh` in each view (orthographic, all the same size), rows
/// from the bottom as [`View::project`] counts them, `f32::INFINITY` where nothing is drawn.
/// `Unsupported` for perspective views and for meshes larger than one storage binding.
pub fn depth_images(gpu: &Gpu, mesh: &Mesh, views: &[View]) -> Result<Vec<Vec<f32>>, GpuError> {
    let Some(pixels) = views.first().map(|v| v.pixels) else {
        return Ok(Vec::new());
    };
    let (origin, positions) = crate::gpu::centred_positions(mesh);
    let mut rows: Vec<[f32; 4]> = Vec::with_capacity(3 * views.len());
    let mut scale = 0f64;
    for view in views {
        let (Some(view_rows), Some(view_scale)) = (view.ortho_rows(origin), view.ortho_scale()) else {
            return Err(GpuError::Unsupported("GPU depth images are orthographic only".into()));
        };
        rows.extend(view_rows.map(|r| r.map(|v| v as f32)));
        scale = scale.max(view_scale);
    }
    // On a software adapter a thread draws its item in as many views as fit its budget with a
    // row of the image each: llvmpipe spends more setting a thread up than drawing a tiny
    // triangle. A hardware GPU runs a thread per item and view at once (on an H200, spider's 160
    // sky views took 11.8 ms of device time drawn 160 to a thread).
    let views_per_thread = match gpu.info.device_type {
        wgpu::DeviceType::Cpu => (THREAD_PIXELS / pixels).clamp(1, views.len()),
        _ => 1,
    };
    let items = work_items(mesh, scale, pixels, views_per_thread);
    let image_bytes = (pixels * pixels * 4) as u64;
    let per_dispatch = ((gpu.max_binding / image_bytes) as usize).min(MAX_VIEWS);
    let largest_input = [mesh.positions.len() * 12, mesh.triangles.len() * 12, items.len() * 16];
    if per_dispatch == 0 || largest_input.into_iter().any(|bytes| bytes as u64 > gpu.max_binding) {
        return Err(GpuError::Unsupported(
            "the mesh or one depth image exceeds the adapter's largest storage binding".into(),
        ));
    }
    if items.is_empty() {
        return Ok(vec![vec![f32::INFINITY; pixels * pixels]; views.len()]);
    }
    gpu.run(|gpu| {
        let positions = gpu.upload(&positions);
        let triangles = gpu.upload(&mesh.triangles);
        let item_buffer = gpu.upload(&items);
        let mut images = Vec::with_capacity(views.len());
        for (chunk, chunk_rows) in views.chunks(per_dispatch).zip(rows.chunks(3 * per_dispatch)) {
            let params = gpu.upload(&[
                pixels as u32,
                chunk.len() as u32,
                items.len() as u32,
                views_per_thread as u32,
            ]);
            let view_buffer = gpu.uniform(chunk_rows, 3 * MAX_VIEWS);
            let depth = gpu.zeroed((pixels * pixels * chunk.len() * 4) as u64);
            let threads = items.len() as u64 * chunk.len().div_ceil(views_per_thread) as u64;
            let groups = u32::try_from(threads.div_ceil(u64::from(WORKGROUP)))
                .map_err(|_| GpuError::Unsupported("too many triangles for one dispatch".into()))?;
            gpu.dispatch(
                SHADER,
                "depth_min",
                &[
                    (0, &params),
                    (1, &positions),
                    (2, &triangles),
                    (3, &item_buffer),
                    (4, &view_buffer),
                    (5, &depth),
                ],
                groups,
            );
            gpu.read_with(&depth, |keys: &[u32]| {
                images.par_extend(
                    keys.par_chunks(pixels * pixels)
                        .map(|image| image.iter().map(|&k| depth_of(k)).collect::<Vec<f32>>()),
                );
            })?;
        }
        Ok(images)
    })
}

/// The depth a shader key stands for (`nearness` in shaders/raster.wgsl, undone).
fn depth_of(key: u32) -> f32 {
    match key {
        EMPTY => f32::INFINITY,
        k if k & 0x8000_0000 != 0 => f32::from_bits(k),
        k => f32::from_bits(!k & 0x7fff_ffff),
    }
}

/// (triangle, first row, rows, 0) per run of rows: a triangle's projected bounds are at most its
/// diameter times `scale` pixels across in any view, and at most the image, split so no thread
/// tests more than `THREAD_PIXELS` pixels over its `views_per_thread` views.
fn work_items(mesh: &Mesh, scale: f64, pixels: usize, views_per_thread: usize) -> Vec<[u32; 4]> {
    let mut items = Vec::with_capacity(mesh.triangles.len());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let corners = tri.map(|v| mesh.positions[v as usize].as_dvec3());
        let centre = (corners[0] + corners[1] + corners[2]) / 3.0;
        let reach = corners.iter().map(|c| c.distance(centre)).fold(0.0, f64::max);
        let side = ((2.0 * reach * scale).ceil() as usize + 2).min(pixels);
        let rows = (THREAD_PIXELS / views_per_thread / side).max(1);
        for first in (0..side).step_by(rows) {
            items.push([t as u32, first as u32, rows as u32, 0]);
        }
    }
    items
}

#[cfg(test)]
mod tests {
    #[test]
    fn depth_keys_grow_nearer_and_come_back_unchanged() {
        // `nearness` in the shader, written out for the test.
        let nearness = |d: f32| {
            let bits = d.to_bits();
            if bits & 0x8000_0000 != 0 {
                bits
            } else {
                !(bits | 0x8000_0000)
            }
        };
        let depths = [-f32::MAX, -3.5f32, -0.0, 0.0, 1e-30, 0.25, 7.0, f32::MAX];
        for pair in depths.windows(2) {
            assert!(nearness(pair[0]) >= nearness(pair[1]), "{pair:?}");
        }
        for d in depths {
            assert_ne!(nearness(d), super::EMPTY);
            assert_eq!(super::depth_of(nearness(d)).to_bits(), d.to_bits());
        }
    }
}
