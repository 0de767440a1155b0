//! Host code for shaders/raster.wgsl: depth images of a mesh from orthographic views, one render
//! pass each, read back in one go. The twin is [`crate::eval::raster::depth_image`].

use super::{Gpu, GpuError};
use crate::eval::raster::View;
use crate::mesh::Mesh;

const SHADER: &str = include_str!("../../shaders/raster.wgsl");

/// The nearest depth per pixel of `mesh` in each view (orthographic, all the same size), rows
/// from the bottom as [`View::project`] counts them, `f32::INFINITY` where nothing is drawn.
pub fn depth_images(gpu: &Gpu, mesh: &Mesh, views: &[View]) -> Result<Vec<Vec<f32>>, GpuError> {
    let Some(pixels) = views.first().map(|v| v.pixels as u32) else {
        return Ok(Vec::new());
    };
    gpu.run(|gpu| {
        let buffers = super::MeshBuffers::new(gpu, mesh);
        let origin = buffers.origin;
        // Both sides, as the twin draws them.
        let pipeline = super::mesh_pipeline(gpu, SHADER, wgpu::CompareFunction::Less, None);
        let row = (pixels * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let image_bytes = u64::from(row) * u64::from(pixels);
        let staging = gpu.staging(image_bytes * views.len() as u64);
        let target = super::render_target(
            gpu,
            super::DEPTH_FORMAT,
            pixels,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let target_view = target.create_view(&Default::default());
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        for (i, view) in views.iter().enumerate() {
            let matrix = view
                .ortho_clip_matrix(origin, view.ortho_margin(mesh))
                .ok_or_else(|| GpuError::Unsupported("GPU depth images are orthographic only".into()))?
                .as_mat4();
            let depth = super::depth_attachment(&target_view, 1.0, true);
            buffers.draw(gpu, &mut encoder, &pipeline, &matrix.to_cols_array(), None, depth);
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: &target,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::DepthOnly,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &staging,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: image_bytes * i as u64,
                        bytes_per_row: Some(row),
                        rows_per_image: None,
                    },
                },
                target.size(),
            );
        }
        let raw: Vec<f32> = gpu.finish_read(encoder, &staging)?;
        let (per_row, n) = (row as usize / 4, pixels as usize);
        Ok(views
            .iter()
            .zip(raw.chunks(per_row * n))
            .map(|(view, image)| {
                let margin = view.ortho_margin(mesh);
                // The GPU's first row is the top one.
                (0..n)
                    .rev()
                    .flat_map(|y| image[y * per_row..y * per_row + n].iter())
                    .map(|&d| match view.ortho_depth(d, margin) {
                        Some(depth) if d < 1.0 => depth,
                        _ => f32::INFINITY,
                    })
                    .collect()
            })
            .collect())
    })
}
