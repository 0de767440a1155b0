//! Host code for shaders/cpsv.wgsl: a batch of seeds' cube maps rendered (a render pass per
//! face, the nearest surface's depth signed by its side), their back-face pixels counted by a
//! compute pass, and the votes of the decided seeds cast by another. The twin is
//! [`super`].

use crate::geom::camera::View;
use crate::gpu::{DEPTH_FORMAT, Gpu, GpuError, MeshBuffers, POSITIONS, depth_attachment, mesh_pipeline, render_target};
use crate::mesh::Mesh;
use glam::DVec3;

const SHADER: &str = include_str!("../../../shaders/cpsv.wgsl");
const IMAGE: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;

/// `Params` in shaders/cpsv.wgsl.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    pixels: u32,
    row_floats: u32,
    faces: u32,
    cells: u32,
    voters: u32,
}

/// `Voter` in shaders/cpsv.wgsl.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Voter {
    eye: [f32; 3],
    near: f32,
    first_face: u32,
    verdict: u32,
    pad: [u32; 2],
}

/// A seed: its cell's centre and the near plane at the cell's edge.
pub struct Seed {
    pub eye: DVec3,
    pub near: f64,
}

/// A mesh ready for cube maps on the device, made once a classification: its buffers, the face
/// pipeline, and the cells' corners (relative to the mesh's origin).
pub struct CubeMaps<'a> {
    gpu: &'a Gpu,
    buffers: MeshBuffers,
    pipeline: wgpu::RenderPipeline,
    pixels: u32,
    corners: Vec<[[f32; 3]; 2]>,
}

impl<'a> CubeMaps<'a> {
    /// `mesh` with cube maps `pixels` a side, and the cells (lowest and highest corner) that
    /// seeds vote in.
    pub fn new(gpu: &'a Gpu, mesh: &Mesh, pixels: u32, cells: &[[DVec3; 2]]) -> Result<CubeMaps<'a>, GpuError> {
        gpu.run(|device| {
            let buffers = MeshBuffers::new(device, mesh);
            let origin = buffers.origin;
            let corners = cells
                .iter()
                .map(|c| c.map(|p| (p - origin).as_vec3().to_array()))
                .collect();
            Ok(CubeMaps {
                gpu,
                buffers,
                // Both sides drawn (which one shows is the point), nearest kept: reversed depth.
                pipeline: mesh_pipeline(
                    device,
                    SHADER,
                    POSITIONS,
                    wgpu::CompareFunction::Greater,
                    Some(("side", IMAGE)),
                ),
                pixels,
                corners,
            })
        })
    }

    /// Renders the seeds' cube maps, asks `verdict` for each seed from its back-face pixels per
    /// face (0 undecided, 1 inside, 2 outside), and counts for each cell still `unknown` the
    /// (inside, outside) votes of the decided seeds that see its eight corners. Returns the
    /// verdicts and the votes.
    pub fn seeds_and_votes(
        &self,
        seeds: &[Seed],
        unknown: &[bool],
        verdict: impl Fn(&[u32]) -> u32,
    ) -> Result<(Vec<u32>, Vec<[u32; 2]>), GpuError> {
        self.gpu.run(|gpu| self.batch(gpu, seeds, unknown, verdict))
    }

    fn batch(
        &self,
        gpu: &Gpu,
        seeds: &[Seed],
        unknown: &[bool],
        verdict: impl Fn(&[u32]) -> u32,
    ) -> Result<(Vec<u32>, Vec<[u32; 2]>), GpuError> {
        let faces = self.render_faces(gpu, seeds);
        let mut params = Params {
            pixels: self.pixels,
            row_floats: faces.row_bytes / 4,
            faces: seeds.len() as u32 * 6,
            cells: self.corners.len() as u32,
            voters: 0,
        };
        let backs = gpu.zeroed(u64::from(params.faces) * 4);
        let groups = (self.pixels * self.pixels * params.faces).div_ceil(64);
        let count_params = gpu.upload(&[params]);
        gpu.dispatch(
            SHADER,
            "count_backs",
            &[(1, &count_params), (2, &faces.images), (3, &backs)],
            groups,
        );
        let backs: Vec<u32> = gpu.read(&backs)?;
        let verdicts: Vec<u32> = backs.chunks(6).map(&verdict).collect();
        let origin = self.buffers.origin;
        let voters: Vec<Voter> = seeds
            .iter()
            .zip(&verdicts)
            .enumerate()
            .filter(|(_, (_, v))| **v != 0)
            .map(|(s, (seed, &v))| Voter {
                eye: (seed.eye - origin).as_vec3().to_array(),
                near: seed.near as f32,
                first_face: s as u32 * 6,
                verdict: v,
                pad: [0; 2],
            })
            .collect();
        if voters.is_empty() || self.corners.is_empty() {
            return Ok((verdicts, vec![[0; 2]; self.corners.len()]));
        }
        params.voters = voters.len() as u32;
        let votes = self.cast_votes(gpu, params, &faces, &voters, unknown)?;
        Ok((verdicts, votes))
    }

    /// Renders the six faces of each seed's cube map, one render pass each, into one buffer of
    /// images.
    fn render_faces(&self, gpu: &Gpu, seeds: &[Seed]) -> Faces {
        let (buffers, pipeline, pixels) = (&self.buffers, &self.pipeline, self.pixels);
        let origin = buffers.origin;
        let faces = seeds.len() as u32 * 6;
        let row = (pixels * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let image_bytes = u64::from(row) * u64::from(pixels);
        let images = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("cpsv faces"),
            size: image_bytes * u64::from(faces),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let image = render_target(
            gpu,
            IMAGE,
            pixels,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let depth = render_target(gpu, DEPTH_FORMAT, pixels, wgpu::TextureUsages::RENDER_ATTACHMENT);
        let (image_view, depth_view) = (
            image.create_view(&Default::default()),
            depth.create_view(&Default::default()),
        );
        let mut clips: Vec<[f32; 16]> = Vec::with_capacity(faces as usize);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        for (s, seed) in seeds.iter().enumerate() {
            for (f, view) in View::cube_map(seed.eye, pixels as usize, seed.near).iter().enumerate() {
                let clip = view
                    .perspective_clip_matrix(origin, seed.near)
                    .expect("cube-map faces are perspective")
                    .as_mat4()
                    .to_cols_array();
                clips.push(clip);
                let color = wgpu::RenderPassColorAttachment {
                    view: &image_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        // Nothing drawn: infinitely far, not a back face.
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: f64::from(f32::MAX),
                            g: 0.0,
                            b: 0.0,
                            a: 0.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                };
                // Reversed depth (near / w): cleared to 0, nearer is greater.
                let depth = depth_attachment(&depth_view, 0.0, false);
                buffers.draw(gpu, &mut encoder, pipeline, &clip, Some(color), depth);
                encoder.copy_texture_to_buffer(
                    image.as_image_copy(),
                    wgpu::TexelCopyBufferInfo {
                        buffer: &images,
                        layout: wgpu::TexelCopyBufferLayout {
                            offset: image_bytes * (s * 6 + f) as u64,
                            bytes_per_row: Some(row),
                            rows_per_image: None,
                        },
                    },
                    image.size(),
                );
            }
        }
        gpu.queue.submit([encoder.finish()]);
        Faces {
            images,
            clips,
            row_bytes: row,
        }
    }

    /// The (inside, outside) votes of `voters` in each cell still `unknown`.
    fn cast_votes(
        &self,
        gpu: &Gpu,
        params: Params,
        faces: &Faces,
        voters: &[Voter],
        unknown: &[bool],
    ) -> Result<Vec<[u32; 2]>, GpuError> {
        let cells = &self.corners;
        let corners: Vec<[f32; 4]> = cells
            .iter()
            .zip(unknown)
            .flat_map(|([a, b], &unknown)| {
                [
                    [a[0], a[1], a[2], f32::from(u8::from(unknown))],
                    [b[0], b[1], b[2], 0.0],
                ]
            })
            .collect();
        let vote_params = gpu.upload(&[params]);
        let (voter_buffer, clip_buffer, cell_buffer) =
            (gpu.upload(voters), gpu.upload(&faces.clips), gpu.upload(&corners));
        let votes = gpu.zeroed(cells.len() as u64 * 8);
        gpu.dispatch(
            SHADER,
            "vote",
            &[
                (1, &vote_params),
                (2, &faces.images),
                (4, &voter_buffer),
                (5, &clip_buffer),
                (6, &cell_buffer),
                (7, &votes),
            ],
            (cells.len() as u32).div_ceil(64),
        );
        gpu.read(&votes)
    }
}

/// A batch's cube-map faces on the device: their images (rows of `row_bytes`) and the clip
/// matrices that drew them.
struct Faces {
    images: wgpu::Buffer,
    clips: Vec<[f32; 16]>,
    row_bytes: u32,
}
