//! Host code for shaders/cull.wgsl: a level's placed meshes in one vertex buffer, rendered per
//! camera into an instance-id target over a reversed float depth buffer; the ids left are the
//! instances with at least one visible pixel. The twin is `ground_truth` in
//! [`super`].

use crate::geom::camera::View;
use crate::gpu::{DEPTH_FORMAT, Gpu, GpuError, depth_attachment, mesh_pipeline, render_target};
use glam::DVec3;
use std::ops::Range;
use wgpu::util::DeviceExt;

const SHADER: &str = include_str!("../../../shaders/cull.wgsl");
const IDS: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// What a pixel holds where nothing is drawn.
const NONE: u32 = u32::MAX;

/// A level on the device, ready to render from any camera.
pub struct InstanceScene<'a> {
    gpu: &'a Gpu,
    origin: DVec3,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    /// Each instance's range in `indices`.
    ranges: Vec<Range<u32>>,
    pipeline: wgpu::RenderPipeline,
    pixels: u32,
    ids: wgpu::Texture,
    depth: wgpu::Texture,
}

impl<'a> InstanceScene<'a> {
    /// `placed` holds each instance's world-space corner positions and its triangles; images
    /// are `pixels` square.
    pub fn new(gpu: &'a Gpu, placed: &[(Vec<DVec3>, &[[u32; 3]])], pixels: u32) -> InstanceScene<'a> {
        let (lo, hi) = crate::mesh::point_bounds(placed.iter().flat_map(|(p, _)| p.iter().copied()));
        // Vertices relative to the level's centre keep f32 precise on large levels.
        let origin = (lo + hi) * 0.5;
        let mut vertices: Vec<[u32; 4]> = Vec::new();
        let mut indices: Vec<u32> = Vec::new();
        let mut ranges = Vec::with_capacity(placed.len());
        for (id, (positions, triangles)) in placed.iter().enumerate() {
            let base = vertices.len() as u32;
            vertices.extend(positions.iter().map(|p| {
                let [x, y, z] = (*p - origin).as_vec3().to_array().map(f32::to_bits);
                [x, y, z, id as u32]
            }));
            let first = indices.len() as u32;
            indices.extend(triangles.iter().flat_map(|t| t.map(|v| base + v)));
            ranges.push(first..indices.len() as u32);
        }
        let buffer = |bytes: &[u8], usage| {
            gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents: if bytes.is_empty() { &[0; 16] } else { bytes },
                usage,
            })
        };
        // Positions and the instance's id; both sides drawn, as the twin draws them.
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: 16,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Uint32],
        };
        let pipeline = mesh_pipeline(
            gpu,
            SHADER,
            vertex_layout,
            wgpu::CompareFunction::Greater,
            Some(("instance_id", IDS)),
        );
        InstanceScene {
            gpu,
            origin,
            vertices: buffer(bytemuck::cast_slice(&vertices), wgpu::BufferUsages::VERTEX),
            indices: buffer(bytemuck::cast_slice(&indices), wgpu::BufferUsages::INDEX),
            ranges,
            pipeline,
            pixels,
            ids: render_target(
                gpu,
                IDS,
                pixels,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            ),
            depth: render_target(gpu, DEPTH_FORMAT, pixels, wgpu::TextureUsages::RENDER_ATTACHMENT),
        }
    }

    /// Which instances show at least one pixel from `view` (perspective, `pixels` wide, near
    /// plane at `near`), drawing only the instances in `candidates`.
    pub fn visible(&self, view: &View, near: f64, candidates: &[usize]) -> Result<Vec<bool>, GpuError> {
        self.gpu.run(|gpu| {
            let matrix = view
                .perspective_clip_matrix(self.origin, near)
                .ok_or_else(|| GpuError::Unsupported("cull-eval renders perspective views only".into()))?
                .as_mat4();
            let camera = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("camera"),
                contents: bytemuck::cast_slice(&matrix.to_cols_array()),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("camera"),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: camera.as_entire_binding(),
                }],
            });
            let ids = self.ids.create_view(&Default::default());
            let depth = self.depth.create_view(&Default::default());
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            {
                let stamp = gpu.stamp();
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("cull"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &ids,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color {
                                r: f64::from(NONE),
                                g: 0.0,
                                b: 0.0,
                                a: 0.0,
                            }),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: Some(depth_attachment(&depth, 0.0, false)),
                    timestamp_writes: stamp.as_ref().map(|s| s.render()),
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.set_vertex_buffer(0, self.vertices.slice(..));
                pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
                for &i in candidates {
                    pass.draw_indexed(self.ranges[i].clone(), 0, 0..1);
                }
            }
            let pixels: Vec<u32> = gpu.read_texture(encoder, &self.ids, self.pixels)?;
            let mut visible = vec![false; self.ranges.len()];
            for &id in pixels.iter().filter(|&&id| id != NONE) {
                visible[id as usize] = true;
            }
            Ok(visible)
        })
    }
}
