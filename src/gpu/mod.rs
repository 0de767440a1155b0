//! One wgpu device per process, and the plumbing the GPU stages share: storage buffers,
//! compute dispatches, read-back and error capture.
//!
//! A hardware adapter is preferred; without one, Mesa's lavapipe (a software Vulkan) runs the
//! same shaders on the CPU. A lost device is dropped and opened again for the next job.

use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use wgpu::util::DeviceExt;

mod precise;
mod timer;

/// Where the GPU stages run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeviceChoice {
    /// A hardware GPU when there is one, else the CPU, saying why in the report.
    Auto,
    /// Any adapter, lavapipe included; fails when there is none.
    Gpu,
    /// The plain-Rust stages.
    Cpu,
}

#[derive(Debug, Clone, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter: wgpu found no Vulkan device (install mesa-vulkan-drivers for lavapipe, or use device=cpu)"
    )]
    NoAdapter,
    #[error("the GPU device could not be opened: {0}")]
    Open(String),
    #[error("the GPU ran out of memory: {0}")]
    OutOfMemory(String),
    #[error("the GPU device was lost: {0}")]
    Lost(String),
    #[error("not done on the GPU: {0}")]
    Unsupported(String),
    #[error("GPU error: {0}")]
    Other(String),
}

/// An open device and the pipelines built on it.
#[derive(Clone)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// The largest storage buffer one binding may hold (lavapipe: 128 MiB).
    pub max_binding: u64,
    lost: Arc<AtomicBool>,
    pipelines: Arc<Mutex<Pipelines>>,
    /// Times the passes recorded through this handle ([`Gpu::timed`]).
    timer: Option<Arc<timer::PassTimer>>,
    /// Passes recorded through this handle since [`Gpu::take_passes`] last read them.
    passes: Arc<AtomicUsize>,
    /// Whether a stage whose work is small runs on the CPU where that is faster
    /// ([`Gpu::pays_for`]): `device=auto`.
    where_it_pays: bool,
}

static DEVICE: Mutex<Option<Arc<Gpu>>> = Mutex::new(None);

/// The device `slot` holds, unless it was lost.
fn held(slot: &Option<Arc<Gpu>>) -> Option<&Arc<Gpu>> {
    slot.as_ref().filter(|g| !g.lost.load(Ordering::Acquire))
}

/// The process's device, opened on first use and again after a loss.
pub fn device() -> Result<Arc<Gpu>, GpuError> {
    let mut slot = DEVICE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(gpu) = held(&slot) {
        return Ok(gpu.clone());
    }
    let gpu = Arc::new(open()?);
    *slot = Some(gpu.clone());
    Ok(gpu)
}

/// Compute pipelines by the address of their source and their entry point, each with its source.
type Pipelines = HashMap<(usize, &'static str), (&'static str, wgpu::ComputePipeline)>;

/// The device for a test of the GPU stages, or `None` (the test skips, and says so) where no
/// adapter exists outside CI: CI installs lavapipe, so there one must.
pub fn device_for_tests() -> Option<Arc<Gpu>> {
    match device() {
        Ok(gpu) => Some(gpu),
        Err(GpuError::NoAdapter) if std::env::var_os("CI").is_none() => {
            eprintln!("no GPU adapter (install mesa-vulkan-drivers for lavapipe); skipping the GPU test");
            None
        }
        Err(e) => panic!("CI installs lavapipe, so a GPU adapter must exist: {e}"),
    }
}

/// Where the stages run for `choice`: the device, or `None` for the CPU with the reason when
/// `auto` chose it.
pub struct Placement {
    pub gpu: Option<Arc<Gpu>>,
    pub why_cpu: Option<String>,
}

/// A CPU thread's share of the work from which a cook's GPU stages save more than opening a
/// device costs, about 250 ms a process on an H200 host of 16 threads (157–191 ms to open, and
/// the first passes). There a mesh with openings saved 357 ms at 13.3 million voxels
/// (bunny-holes at 256³), 180 ms at 5.7 million (at 192³) and 86 ms at 5.4 million (teapot at
/// 256³); 2cylinder-engine's exposure depth images saved about 50 ms for its 110,336 triangles at
/// any grid. A closed mesh, with surface and inside alone on the GPU, saved 15 ms at 9.4 million
/// voxels (spot at 256³).
const OPEN_VOXELS_A_THREAD: f64 = 500_000.0;
const OPEN_TRIANGLES_A_THREAD: f64 = 35_000.0;
const CLOSED_VOXELS_A_THREAD: f64 = 8_000_000.0;

/// What a cook's GPU stages work on.
#[derive(Clone, Copy, Debug)]
pub struct CookSize {
    pub voxels: usize,
    pub triangles: usize,
    /// Whether the mesh has openings: only then do the exposure stages, which also grow with
    /// the triangles, run.
    pub open: bool,
}

impl CookSize {
    /// Whether its GPU stages save more than opening a device costs, against `threads` CPU
    /// threads.
    fn pays_for_opening(&self, threads: usize) -> bool {
        let shares = match self.open {
            true => self.voxels as f64 / OPEN_VOXELS_A_THREAD + self.triangles as f64 / OPEN_TRIANGLES_A_THREAD,
            false => self.voxels as f64 / CLOSED_VOXELS_A_THREAD,
        };
        shares >= threads as f64
    }
}

/// The device for a cook of `size` under `choice`. Under `auto`, a process that has no device
/// open yet (a one-shot `cook`) runs a cook too small for the GPU to pay for its opening on the
/// CPU, without looking for an adapter; a process that cooks many meshes opens it first
/// ([`for_choice`]), so every cook of its uses it.
pub fn for_cook(choice: DeviceChoice, size: CookSize) -> Result<Placement, GpuError> {
    let threads = rayon::current_num_threads();
    if choice == DeviceChoice::Auto && !size.pays_for_opening(threads) && !is_open() {
        let CookSize { voxels, triangles, .. } = size;
        let mesh = match size.open {
            true => "a mesh with openings",
            false => "a closed mesh",
        };
        return Ok(Placement {
            gpu: None,
            why_cpu: Some(format!(
                "device=auto ran this cook on the CPU: on {threads} threads, {voxels} voxels of {mesh} of {triangles} \
                 triangles take less time there than opening a GPU (README, GPU); a process with one open uses it"
            )),
        });
    }
    for_choice(choice)
}

/// Whether this process has a device open.
fn is_open() -> bool {
    held(&DEVICE.lock().unwrap_or_else(|e| e.into_inner())).is_some()
}

/// The device for `choice`. `auto` takes a hardware adapter only: on a software one (lavapipe)
/// the CPU stages measured faster (README, "GPU"), so `gpu` must ask for it.
pub fn for_choice(choice: DeviceChoice) -> Result<Placement, GpuError> {
    let cpu = |why: String| Placement {
        gpu: None,
        why_cpu: Some(why),
    };
    match choice {
        DeviceChoice::Cpu => Ok(Placement {
            gpu: None,
            why_cpu: None,
        }),
        DeviceChoice::Gpu => device().map(|gpu| Placement {
            gpu: Some(gpu),
            why_cpu: None,
        }),
        DeviceChoice::Auto => match best_adapter_info() {
            None => Ok(cpu(
                "device=auto found no GPU adapter, so the stages ran on the CPU".into()
            )),
            Some(info) if info.device_type == wgpu::DeviceType::Cpu => Ok(cpu(format!(
                "device=auto found only a software adapter ({}), where the CPU stages are faster; device=gpu uses it",
                info.name
            ))),
            Some(_) => device().map(|gpu| Placement {
                gpu: Some(gpu),
                why_cpu: None,
            }),
        },
    }
}

fn rank(kind: wgpu::DeviceType) -> u8 {
    match kind {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

/// The process's wgpu instance. Making one loads the drivers, 80–95 ms a time on an H200's, so
/// looking for an adapter and opening it share one; the adapters are found afresh for each
/// device, as an adapter opens one device.
fn instance() -> &'static wgpu::Instance {
    static INSTANCE: std::sync::OnceLock<wgpu::Instance> = std::sync::OnceLock::new();
    INSTANCE.get_or_init(|| wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env()))
}

/// The preferred adapter: hardware first, lavapipe last.
fn best_adapter() -> Option<wgpu::Adapter> {
    let adapters = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::all()));
    adapters.into_iter().min_by_key(|a| rank(a.get_info().device_type))
}

/// What [`device`] would open, looked up once a process without opening it.
pub fn best_adapter_info() -> Option<wgpu::AdapterInfo> {
    static INFO: std::sync::OnceLock<Option<wgpu::AdapterInfo>> = std::sync::OnceLock::new();
    INFO.get_or_init(|| best_adapter().map(|a| a.get_info())).clone()
}

fn open() -> Result<Gpu, GpuError> {
    let adapter = best_adapter().ok_or(GpuError::NoAdapter)?;
    let info = adapter.get_info();
    let supported = adapter.limits();
    // Ask for what the adapter has, so large grids need fewer slabs.
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: supported.max_storage_buffer_binding_size,
        max_buffer_size: supported.max_buffer_size,
        ..wgpu::Limits::default()
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("occluder-cook"),
        required_features: adapter.features() & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::PASSTHROUGH_SHADERS),
        required_limits: limits.clone(),
        ..Default::default()
    }))
    .map_err(|e| GpuError::Open(e.to_string()))?;
    let lost = Arc::new(AtomicBool::new(false));
    let flag = lost.clone();
    device.set_device_lost_callback(move |reason, message| {
        tracing::error!(?reason, message, "GPU device lost");
        flag.store(true, Ordering::Release);
    });
    tracing::info!(adapter = info.name, kind = ?info.device_type, "GPU device opened");
    let gpu = Gpu {
        device,
        queue,
        info,
        max_binding: limits.max_storage_buffer_binding_size.min(limits.max_buffer_size),
        lost,
        pipelines: Arc::new(Mutex::new(HashMap::new())),
        timer: None,
        passes: Arc::new(AtomicUsize::new(0)),
        where_it_pays: false,
    };
    Ok(gpu)
}

/// The float depth buffer of the render stages.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Depth testing with `compare`, writing the depth that passes.
pub fn depth_test(compare: wgpu::CompareFunction) -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(true),
        depth_compare: Some(compare),
        stencil: Default::default(),
        bias: Default::default(),
    }
}

/// A depth attachment cleared to `clear`, kept for a copy when `keep`.
pub fn depth_attachment(
    view: &wgpu::TextureView,
    clear: f32,
    keep: bool,
) -> wgpu::RenderPassDepthStencilAttachment<'_> {
    wgpu::RenderPassDepthStencilAttachment {
        view,
        depth_ops: Some(wgpu::Operations {
            load: wgpu::LoadOp::Clear(clear),
            store: if keep {
                wgpu::StoreOp::Store
            } else {
                wgpu::StoreOp::Discard
            },
        }),
        stencil_ops: None,
    }
}

/// The centre of `mesh`'s bounds and its positions relative to it, in f32: precise far from the
/// world's origin.
pub(crate) fn centred_positions(mesh: &crate::mesh::Mesh) -> (glam::DVec3, Vec<[f32; 3]>) {
    let (lo, hi) = mesh.bounds();
    let origin = ((lo + hi) * 0.5).as_dvec3();
    let positions = mesh
        .positions
        .iter()
        .map(|p| (p.as_dvec3() - origin).as_vec3().to_array())
        .collect();
    (origin, positions)
}

/// A mesh on the device for the render stages: positions relative to the centre of its bounds
/// (which keeps f32 precise far from the world's origin) and indices.
pub(crate) struct MeshBuffers {
    pub origin: glam::DVec3,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    corners: u32,
}

impl MeshBuffers {
    pub fn new(gpu: &Gpu, mesh: &crate::mesh::Mesh) -> MeshBuffers {
        let (origin, positions) = centred_positions(mesh);
        let init = |contents: &[u8], usage| {
            gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents,
                usage,
            })
        };
        MeshBuffers {
            origin,
            vertices: init(bytemuck::cast_slice(&positions), wgpu::BufferUsages::VERTEX),
            indices: init(bytemuck::cast_slice(&mesh.triangles), wgpu::BufferUsages::INDEX),
            corners: mesh.triangles.len() as u32 * 3,
        }
    }

    /// Records a render pass drawing the mesh through `pipeline`, whose binding 0 is `clip`
    /// (clip space from positions relative to [`MeshBuffers::origin`]).
    pub fn draw(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::RenderPipeline,
        clip: &[f32; 16],
        color: Option<wgpu::RenderPassColorAttachment>,
        depth: wgpu::RenderPassDepthStencilAttachment,
    ) {
        let camera = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("camera"),
            contents: bytemuck::cast_slice(clip),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("camera"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: camera.as_entire_binding(),
            }],
        });
        let colors: Vec<_> = color.into_iter().map(Some).collect();
        let stamp = gpu.stamp();
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: None,
            color_attachments: &colors,
            depth_stencil_attachment: Some(depth),
            timestamp_writes: stamp.as_ref().map(|s| s.render()),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.set_vertex_buffer(0, self.vertices.slice(..));
        pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(0..self.corners, 0, 0..1);
    }
}

/// A square render target of one layer.
pub(crate) fn render_target(
    gpu: &Gpu,
    format: wgpu::TextureFormat,
    pixels: u32,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d {
            width: pixels,
            height: pixels,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

const POSITION_ATTRIBUTES: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![0 => Float32x3];

/// The vertices of [`MeshBuffers`]: three floats each.
pub(crate) const POSITIONS: wgpu::VertexBufferLayout<'static> = wgpu::VertexBufferLayout {
    array_stride: 12,
    step_mode: wgpu::VertexStepMode::Vertex,
    attributes: &POSITION_ATTRIBUTES,
};

/// A pipeline drawing vertices laid out as `vertices` through `source`'s vertex entry `place`,
/// both sides, depth-tested with `compare`, and with `fragment` (an entry and its target's
/// format) where a colour is written.
pub(crate) fn mesh_pipeline(
    gpu: &Gpu,
    source: &str,
    vertices: wgpu::VertexBufferLayout,
    compare: wgpu::CompareFunction,
    fragment: Option<(&str, wgpu::TextureFormat)>,
) -> wgpu::RenderPipeline {
    let module = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: None,
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let targets = fragment.map(|(_, format)| [Some(format.into())]);
    gpu.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: None,
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("place"),
            compilation_options: Default::default(),
            buffers: &[Some(vertices)],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: Some(depth_test(compare)),
        multisample: Default::default(),
        fragment: fragment
            .zip(targets.as_ref())
            .map(|((entry, _), targets)| wgpu::FragmentState {
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                targets,
            }),
        multiview_mask: None,
        cache: None,
    })
}

/// Threads in a workgroup, as the compute shaders declare.
pub const WORKGROUP: u32 = 64;

/// Work items one pass has before each item's share of the work grows past its least (16 MiB of
/// `[u32; 4]` items): large triangles on a fine grid or image cannot size the list.
pub const MAX_ITEMS: usize = 1 << 20;

/// The units of `work` one work item takes: `least`, or more where that would make over
/// [`MAX_ITEMS`] items, up to `most`; at least one.
pub fn units_per_item(work: usize, [least, most]: [usize; 2]) -> usize {
    work.div_ceil(MAX_ITEMS).max(least).min(most).max(1)
}

/// Workgroups are dispatched in a 2D grid of at most this many along x.
pub const MAX_GROUPS_X: u32 = 65535;

impl Gpu {
    /// "lavapipe (cpu)", "NVIDIA H100 (discretegpu)": what reports call the device.
    pub fn name(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.device_type).to_lowercase()
    }

    /// The same device with a smaller largest binding, so that a test or a shared machine can
    /// force slabs.
    pub fn with_max_binding(&self, bytes: u64) -> Gpu {
        Gpu {
            max_binding: bytes.min(self.max_binding),
            ..self.clone()
        }
    }

    /// The same device, timing and counting the passes recorded through this handle alone (so
    /// concurrent cooks keep theirs apart); untimed where the adapter has no timestamp queries.
    pub fn timed(&self) -> Gpu {
        let timestamps = self.device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        Gpu {
            timer: timestamps.then(|| Arc::new(timer::PassTimer::new())),
            passes: Arc::new(AtomicUsize::new(0)),
            ..self.clone()
        }
    }

    /// The same device, on which stages with little work run on the CPU where that is faster
    /// when `yes`.
    pub fn where_it_pays(&self, yes: bool) -> Gpu {
        Gpu {
            where_it_pays: yes,
            ..self.clone()
        }
    }

    /// Whether a stage should run on this device rather than on the CPU: always, unless it was
    /// asked to run only where it pays and the CPU's share of `work`, over the threads it has,
    /// is at most `cpu_beats_gpu`, the work a CPU thread does in the time the stage's fixed
    /// costs on the GPU (uploads, read-backs) take.
    pub fn pays_for(&self, work: usize, cpu_beats_gpu: usize) -> bool {
        !self.where_it_pays || work > cpu_beats_gpu.saturating_mul(rayon::current_num_threads())
    }

    /// How many passes were recorded through this handle since the last call.
    pub fn take_passes(&self) -> usize {
        self.passes.swap(0, Ordering::AcqRel)
    }

    /// Where the next pass writes its times, on a timed handle; counts the pass.
    pub(crate) fn stamp(&self) -> Option<timer::PassStamp> {
        self.passes.fetch_add(1, Ordering::AcqRel);
        self.timer.as_ref().map(|t| t.stamp(&self.device))
    }

    /// The device's milliseconds for the passes submitted since the last call, on a timed
    /// handle.
    pub fn take_device_ms(&self) -> Result<Option<f64>, GpuError> {
        self.timer.as_ref().map(|t| t.take_ms(self)).transpose()
    }

    /// Runs `work` and turns the device's out-of-memory, validation and loss into an error for
    /// this job alone.
    pub fn run<T>(&self, work: impl FnOnce(&Gpu) -> Result<T, GpuError>) -> Result<T, GpuError> {
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = work(self);
        let invalid = pollster::block_on(validation.pop());
        let oom = pollster::block_on(memory.pop());
        if self.lost.load(Ordering::Acquire) {
            return Err(GpuError::Lost("the driver reset or removed the device".into()));
        }
        if let Some(e) = oom {
            return Err(GpuError::OutOfMemory(e.to_string()));
        }
        if let Some(e) = invalid {
            return Err(GpuError::Other(e.to_string()));
        }
        out
    }

    pub fn upload<T: bytemuck::Pod>(&self, data: &[T]) -> wgpu::Buffer {
        // Zero-sized bindings are invalid; an empty array still gets room for one vec4.
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let padded;
        let contents = if bytes.is_empty() {
            padded = [0u8; 16];
            &padded[..]
        } else {
            bytes
        };
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        })
    }

    /// A uniform buffer of `data` zero-padded to `len` elements: a shader's fixed-size array,
    /// for small tables every lane reads (views' rows, the winding stage's open edges).
    pub fn uniform<T: bytemuck::Pod>(&self, data: &[T], len: usize) -> wgpu::Buffer {
        let mut padded = data.to_vec();
        padded.resize(len.max(data.len()), T::zeroed());
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::cast_slice(&padded),
            usage: wgpu::BufferUsages::UNIFORM,
        })
    }

    /// A zeroed storage buffer of `bytes` (rounded up to a word).
    pub fn zeroed(&self, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes.max(4).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    /// Builds the compute pipelines of `entry_points` (shader source, entry) now, so that no
    /// later pass pays for their compilation; each is built once a device.
    pub fn build_pipelines(&self, entry_points: &[(&'static str, &'static str)]) -> Result<(), GpuError> {
        self.run(|gpu| {
            for &(source, entry) in entry_points {
                gpu.pipeline(source, entry);
            }
            Ok(())
        })
    }

    fn pipeline(&self, source: &'static str, entry: &'static str) -> wgpu::ComputePipeline {
        let mut cache = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
        let key = (source.as_ptr() as usize, entry);
        if let Some((_, pipeline)) = cache.get(&key) {
            return pipeline.clone();
        }
        // A `const` source is copied where it is used, so the pipelines built ahead and those a
        // stage asks for can name one text at two addresses: the text decides, once an address
        // misses.
        let built = cache
            .iter()
            .find(|((_, e), (text, _))| *e == entry && *text == source)
            .map(|(_, (_, pipeline))| pipeline.clone());
        let pipeline = built.unwrap_or_else(|| self.build_pipeline(source, entry));
        cache.insert(key, (source, pipeline.clone()));
        pipeline
    }

    fn build_pipeline(&self, source: &'static str, entry: &'static str) -> wgpu::ComputePipeline {
        let (module, layout) = match self.precise_module(source, entry) {
            Some((module, layout)) => (module, Some(layout)),
            None => (
                self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(entry),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                }),
                None,
            ),
        };
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: layout.as_ref(),
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    }

    /// `entry` of `source` as SPIR-V with no contracted float arithmetic ([`precise`]), and
    /// the layout of what it binds; `None` where the device takes no SPIR-V (not Vulkan), and
    /// then the WGSL goes to wgpu as it is.
    fn precise_module(&self, source: &str, entry: &str) -> Option<(wgpu::ShaderModule, wgpu::PipelineLayout)> {
        if !self.device.features().contains(wgpu::Features::PASSTHROUGH_SHADERS) {
            return None;
        }
        let compiled = precise::PreciseEntry::compile(source, entry)
            .inspect_err(|e| tracing::warn!(entry, error = e, "shader kept as WGSL: naga refused it"))
            .ok()??;
        // Safety: the words are naga's own output for a module it validated, with only
        // NoContraction decorations added and wgpu's bounds checks, for this layout.
        let module = unsafe {
            self.device
                .create_shader_module_passthrough(wgpu::ShaderModuleDescriptorPassthrough {
                    label: Some(entry),
                    entry_points: vec![wgpu::PassthroughShaderEntryPoint {
                        name: entry.to_owned().into(),
                        workgroup_size: compiled.workgroup_size.into(),
                    }]
                    .into(),
                    spirv: Some(compiled.words.into()),
                    ..Default::default()
                })
        };
        let group = self.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(entry),
            entries: &compiled.bindings,
        });
        let layout = self.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(entry),
            bind_group_layouts: &[Some(&group)],
            immediate_size: 0,
        });
        Some((module, layout))
    }

    /// Dispatches `groups` workgroups of `entry` in `source`, with `buffers` at their bindings of
    /// group 0 (only those the entry point uses). Large counts are spread over y; shaders
    /// rebuild the flat index as `id.x + id.y * MAX_GROUPS_X`.
    pub fn dispatch(&self, source: &'static str, entry: &'static str, buffers: &[(u32, &wgpu::Buffer)], groups: u32) {
        if groups == 0 {
            return;
        }
        let pipeline = self.pipeline(source, entry);
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .map(|&(binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(entry),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let stamp = self.stamp();
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(entry),
                timestamp_writes: stamp.as_ref().map(|s| s.compute()),
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(groups.min(MAX_GROUPS_X), groups.div_ceil(MAX_GROUPS_X), 1);
        }
        self.queue.submit([encoder.finish()]);
    }

    /// Copies `buffer` back to the host once the queued work is done.
    pub fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        self.read_with(buffer, <[T]>::to_vec)
    }

    /// Hands `buffer`'s contents, once the queued work is done, to `take` where the host sees
    /// them mapped: a large buffer is read once, in parallel where `take` is, rather than first
    /// copied by one thread (on an H200 host, 42 MB of depth images took 25-40 ms so).
    pub fn read_with<T: bytemuck::Pod, R>(
        &self,
        buffer: &wgpu::Buffer,
        take: impl FnOnce(&[T]) -> R,
    ) -> Result<R, GpuError> {
        let size = buffer.size();
        let staging = self.staging(size);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.finish_read_with(encoder, &staging, take)
    }

    /// Runs `encoder`, then copies a square 4-byte-texel `texture` back, row by row (only the
    /// set of values matters to callers, so rows stay top first).
    pub fn read_texture<T: bytemuck::Pod>(
        &self,
        mut encoder: wgpu::CommandEncoder,
        texture: &wgpu::Texture,
        pixels: u32,
    ) -> Result<Vec<T>, GpuError> {
        let row = (pixels * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let staging = self.staging(u64::from(row) * u64::from(pixels));
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: None,
                },
            },
            texture.size(),
        );
        let padded: Vec<T> = self.finish_read(encoder, &staging)?;
        let (per_row, used) = (row as usize / 4, pixels as usize);
        Ok(padded.chunks(per_row).flat_map(|r| r[..used].iter().copied()).collect())
    }

    pub(crate) fn staging(&self, size: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Submits `encoder`, waits, and copies `staging` back.
    pub(crate) fn finish_read<T: bytemuck::Pod>(
        &self,
        encoder: wgpu::CommandEncoder,
        staging: &wgpu::Buffer,
    ) -> Result<Vec<T>, GpuError> {
        self.finish_read_with(encoder, staging, <[T]>::to_vec)
    }

    /// Submits `encoder`, waits, maps `staging` and hands its contents to `take`.
    fn finish_read_with<T: bytemuck::Pod, R>(
        &self,
        encoder: wgpu::CommandEncoder,
        staging: &wgpu::Buffer,
        take: impl FnOnce(&[T]) -> R,
    ) -> Result<R, GpuError> {
        self.queue.submit([encoder.finish()]);
        let (sender, receiver) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = sender.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Other(e.to_string()))?;
        match receiver.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(GpuError::Other(format!("read-back failed: {e}"))),
            Err(_) => return Err(GpuError::Lost("read-back never completed".into())),
        }
        let view = staging
            .get_mapped_range(..)
            .map_err(|e| GpuError::Other(e.to_string()))?;
        let out = take(bytemuck::cast_slice(&view));
        drop(view);
        staging.unmap();
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_a_device_pays_for_the_cooks_it_paid_for_on_an_h200() {
        let size = |voxels: f64, triangles, open| CookSize {
            voxels: (voxels * 1e6) as usize,
            triangles,
            open,
        };
        // The H200 host's 16 threads: the sizes of the measurements behind the shares.
        let paid = [
            (size(13.28, 69_451, true), true),
            (size(5.65, 69_451, true), false),
            (size(5.35, 6_320, true), false),
            (size(2.38, 110_336, true), false),
            (size(0.16, 5_856, false), false),
            (size(9.37, 5_856, false), false),
        ];
        for (cook, pays) in paid {
            assert_eq!(cook.pays_for_opening(16), pays, "{cook:?}");
        }
        // Fewer threads take longer over the same work: the GPU pays sooner.
        assert!(size(5.65, 69_451, true).pays_for_opening(8));
        assert!(size(1.0, 40_000, true).pays_for_opening(2));
        assert!(!size(1.0, 40_000, false).pays_for_opening(2));
    }

    #[test]
    fn only_a_handle_placing_by_cost_leaves_work_the_cpu_threads_share_quickly_to_them() {
        let Some(gpu) = device_for_tests() else {
            return;
        };
        let threads = rayon::current_num_threads();
        assert!(gpu.pays_for(0, 1000));
        let auto = gpu.where_it_pays(true);
        assert!(!auto.pays_for(1000 * threads, 1000));
        assert!(auto.pays_for(1000 * threads + 1, 1000));
        assert!(auto.where_it_pays(false).pays_for(0, 1000));
    }

    #[test]
    fn one_shader_text_at_two_addresses_is_built_once() {
        let Some(gpu) = device_for_tests() else {
            return;
        };
        let source: &'static str = "@group(0) @binding(0) var<storage, read_write> out: array<u32>;
            @compute @workgroup_size(1) fn one_text() { out[0] = 1u; }";
        let copy: &'static str = String::from(source).leak();
        assert_ne!(source.as_ptr(), copy.as_ptr());
        let built = gpu.pipeline(source, "one_text");
        assert!(
            gpu.pipeline(copy, "one_text") == built,
            "the copy's text was built again"
        );
        assert!(gpu.pipeline(source, "one_text") == built);
    }
}
