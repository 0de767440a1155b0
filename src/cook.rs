//! One mesh through the whole pipeline: orient, voxelize, classify, expand boxes, refine,
//! select by silhouette, merge, and optionally evaluate.

use crate::config::Settings;
use crate::eval::{Quality, evaluate};
use crate::gpu::{self, GpuError};
use crate::key::{PIPELINE_VERSION, cache_key};
use crate::mesh::{IngestStats, Mesh, Topology, glb, topology::orient_closed_components};
use crate::occluder::{Occluder, Panel, Shape, WorldBox, boxes, exposure::OpenViews, patches, quads, refine, select};
use crate::voxel::{self, Grid, InsideMethod, winding::WindingField};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// How long each stage took, in milliseconds, in pipeline order.
#[derive(Clone, Debug, Default)]
pub struct Timings(pub Vec<(String, f64)>);

impl Serialize for Timings {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (stage, ms) in &self.0 {
            map.serialize_entry(stage, ms)?;
        }
        map.end()
    }
}

/// The stages of a cook, in order, for progress reports.
pub const STAGES: [&str; 17] = [
    "ingest",
    "key",
    "orient",
    "device",
    "surface",
    "inside",
    "inner",
    "exposure-render",
    "exposure-voxels",
    "boxes",
    "refine",
    "exposure-boxes",
    "quads",
    "exposure-quads",
    "patches",
    "select+merge",
    "eval",
];

/// Told each stage as it starts, with the share of the stages done (0..1).
pub type Progress<'a> = &'a (dyn Fn(&str, f64) + Sync);

/// Times the stages and reports each as it starts.
struct Clock<'a> {
    timings: Timings,
    /// The device's own time per stage, where it has timestamp queries.
    device_timings: Timings,
    /// The timed device handle, once open.
    gpu: Option<Arc<gpu::Gpu>>,
    progress: Progress<'a>,
}

impl Clock<'_> {
    fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        let done = STAGES.iter().position(|s| *s == stage).unwrap_or(0);
        (self.progress)(stage, done as f64 / STAGES.len() as f64);
        let start = Instant::now();
        let out = f();
        self.timings.add(stage, start.elapsed().as_secs_f64() * 1e3);
        match self.gpu.as_ref().map(|g| g.take_device_ms()) {
            Some(Ok(Some(ms))) if ms > 0.0 => self.device_timings.add(stage, ms),
            Some(Err(e)) => tracing::warn!(stage, "the device's pass times could not be read: {e}"),
            _ => {}
        }
        out
    }
}

impl Timings {
    /// A stage that runs in several places adds up under one name.
    fn add(&mut self, stage: &str, ms: f64) {
        match self.0.iter_mut().find(|(s, _)| s == stage) {
            Some((_, total)) => *total += ms,
            None => self.0.push((stage.to_string(), ms)),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    pub fn total(&self) -> f64 {
        self.0.iter().map(|(_, ms)| ms).sum()
    }

    pub fn get(&self, stage: &str) -> f64 {
        self.0.iter().find(|(s, _)| s == stage).map_or(0.0, |(_, ms)| *ms)
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub pipeline_version: &'static str,
    pub key: String,
    pub input: InputReport,
    pub grid: Grid,
    pub voxels: VoxelReport,
    pub boxes: BoxReport,
    pub panels: PanelReport,
    pub occluder: OccluderReport,
    /// The device that ran the voxel stages: "cpu", or the GPU adapter's name.
    pub device: String,
    /// The stages that ran on that GPU.
    pub gpu_stages: Vec<&'static str>,
    /// Wall-clock milliseconds per stage, waits for the device included.
    pub timings_ms: Timings,
    /// The device's own milliseconds per stage: its passes, from timestamp queries. Empty on
    /// the CPU and on adapters without timestamps.
    #[serde(skip_serializing_if = "Timings::is_empty")]
    pub device_timings_ms: Timings,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quality: Option<Quality>,
    /// Why the occluder is empty or smaller than asked, in words.
    pub notes: Vec<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct InputReport {
    #[serde(flatten)]
    pub ingest: IngestStats,
    pub triangles: usize,
    #[serde(flatten)]
    pub topology: Topology,
}

#[derive(Clone, Debug, Serialize)]
pub struct VoxelReport {
    pub surface: usize,
    pub solid: usize,
    pub inner: usize,
    /// Inner voxels left out because they show through an opening (open meshes only).
    pub exposed: usize,
    /// Cells, seeds and undecided cells of `inside = "cpsv"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpsv: Option<crate::voxel::cpsv::CpsvStats>,
}

#[derive(Clone, Debug, Serialize)]
pub struct BoxReport {
    pub candidates: usize,
    /// Candidates rejected because they show through an opening (open meshes only).
    pub exposed: usize,
    pub kept: usize,
    /// Share of the inner voxels that the kept boxes fill.
    pub inner_volume_covered: f64,
    pub kept_boxes: Vec<WorldBox>,
}

#[derive(Clone, Debug, Serialize)]
pub struct PanelReport {
    /// In-solid quads found, before selection.
    pub quad_candidates: usize,
    /// On-surface patches found, before selection.
    pub patch_candidates: usize,
    /// Quads rejected because they show through an opening (open meshes only).
    pub exposed: usize,
    pub kept_panels: Vec<Panel>,
}

#[derive(Clone, Debug, Serialize)]
pub struct OccluderReport {
    pub triangles: usize,
    pub vertices: usize,
    pub boxes: usize,
    pub quads: usize,
    pub patches: usize,
    /// Silhouette share each piece added when it was chosen, in the order chosen.
    pub silhouette_gains: Vec<f64>,
}

pub struct Cooked {
    pub occluder: Occluder,
    pub report: Report,
}

impl Cooked {
    /// The occluder as a GLB: the watertight solid and the double-sided panels as two
    /// primitives, with the key and counts in `extras`.
    pub fn glb(&self) -> Vec<u8> {
        let r = &self.report;
        let extras = serde_json::json!({
            "key": r.key,
            "pipeline_version": r.pipeline_version,
            "source_triangles": r.input.triangles,
            "boxes": r.occluder.boxes,
            "quads": r.occluder.quads,
            "patches": r.occluder.patches,
            "triangles": r.occluder.triangles,
        });
        let panels = crate::occluder::panel_mesh(&self.occluder.panels);
        let parts = [
            glb::Part {
                name: "occluder-solid",
                mesh: &self.occluder.solid,
                double_sided: false,
            },
            glb::Part {
                name: "occluder-panels",
                mesh: &panels,
                double_sided: true,
            },
        ];
        glb::write(&parts, extras)
    }
}

/// Cooks an ingested mesh. `ingest_ms` is the time the caller spent reading it. Fails only when
/// the GPU it was told to use is missing or fails.
pub fn cook(
    mesh: Mesh,
    ingest: IngestStats,
    ingest_ms: f64,
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, GpuError> {
    cook_with_progress(mesh, ingest, ingest_ms, settings, with_eval, &|_, _| {})
}

/// [`cook`], telling `progress` each stage as it starts.
pub fn cook_with_progress(
    mut mesh: Mesh,
    ingest: IngestStats,
    ingest_ms: f64,
    settings: &Settings,
    with_eval: bool,
    progress: Progress,
) -> Result<Cooked, GpuError> {
    let cook = &settings.cook;
    let mut timings = Clock {
        timings: Timings(vec![("ingest".into(), ingest_ms)]),
        device_timings: Timings::default(),
        gpu: None,
        progress,
    };
    let key = timings.time("key", || cache_key(&mesh, cook));
    let topology = timings.time("orient", || orient_closed_components(&mut mesh));
    // Opening the device and building its pipelines happens once a process.
    let placement = timings.time("device", || gpu::for_choice(cook.device))?;
    let gpu = placement.gpu.map(|g| Arc::new(g.timed()));
    timings.gpu = gpu.clone();
    let mut notes: Vec<String> = placement.why_cpu.into_iter().collect();
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, cook.resolution);
    let surface = timings.time("surface", || voxel::surface(&mesh, &grid, gpu.as_deref()))?;
    let mut gpu_stages = if gpu.is_some() {
        vec!["surface", "inside"]
    } else {
        Vec::new()
    };
    let cpsv_settings = cook.cpsv();
    let classify = |gpu| voxel::classify(cook.inside, &mesh, &topology, &grid, &surface, &cpsv_settings, gpu);
    let classified = timings.time("inside", || match classify(gpu.as_deref()) {
        Err(GpuError::Unsupported(why)) => {
            notes.push(format!("inside ran on the CPU: {why}"));
            gpu_stages.retain(|s| *s != "inside");
            classify(None)
        }
        result => result,
    })?;
    let solid = classified.solid;
    if let Some(stats) = &classified.cpsv
        && stats.undecided_cells > 0
    {
        notes.push(format!(
            "cpsv left {} of {} cells ({} voxels) undecided; they count as outside",
            stats.undecided_cells, stats.cells, stats.undecided_voxels
        ));
    }
    let mut inner: Vec<bool> = timings.time("inner", || solid.iter().zip(&surface).map(|(&s, &t)| s && !t).collect());
    // Only open meshes can show their inside.
    let open_views = match topology.boundary.is_empty() {
        true => None,
        false => {
            if gpu.is_some() {
                gpu_stages.extend(["exposure-render", "exposure-voxels"]);
            }
            Some(timings.time("exposure-render", || {
                OpenViews::new(&mesh, &topology.boundary, gpu.as_deref())
            })?)
        }
    };
    let exposed_voxels = match &open_views {
        None => 0,
        Some(views) => timings.time("exposure-voxels", || {
            views.remove_exposed(&grid, &mut inner, gpu.as_deref())
        })?,
    };
    let inner_count = inner.iter().filter(|&&v| v).count();
    let expansion = boxes::ExpansionSettings {
        target_coverage: cook.target_coverage,
        min_box_gain: cook.min_box_gain,
        max_boxes: cook.max_boxes,
        min_box_voxels: cook.min_box_voxels,
    };
    let use_shape = |shape: Shape| cook.shapes.contains(&shape);
    let voxel_boxes = if use_shape(Shape::Boxes) {
        timings.time("boxes", || boxes::expand(&inner, grid.dims, &expansion))
    } else {
        Vec::new()
    };
    // Refinement and quads both look triangles up through it.
    let field = timings.time("refine", || WindingField::new(&mesh, &topology.boundary));
    let candidates: Vec<(WorldBox, WorldBox)> = timings.time("refine", || {
        let mut owner = vec![u32::MAX; grid.len()];
        for (id, b) in voxel_boxes.iter().enumerate() {
            for x in b.lo[0]..b.hi[0] {
                for y in b.lo[1]..b.hi[1] {
                    owner[grid.index(x, y, b.lo[2])..grid.index(x, y, b.hi[2])].fill(id as u32);
                }
            }
        }
        let input = refine::RefineInput {
            mesh: &mesh,
            grid: &grid,
            field: &field,
            solid: &solid,
            owner: &owner,
        };
        voxel_boxes
            .iter()
            .enumerate()
            .map(|(id, b)| {
                let on_grid = WorldBox::from_voxels(&grid, b);
                let refined = cook.refine.then(|| refine::refine(&input, id as u32, b));
                (refined.unwrap_or(on_grid), on_grid)
            })
            .collect()
    });
    // Near an opening a refined face can reach past the solid; such a box falls back to its
    // voxels, and is dropped if even those show.
    let candidates: Vec<WorldBox> = match &open_views {
        None => candidates.into_iter().map(|(refined, _)| refined).collect(),
        Some(views) => timings.time("exposure-boxes", || {
            candidates
                .into_par_iter()
                .filter_map(|(refined, on_grid)| {
                    [refined, on_grid]
                        .into_iter()
                        .find(|b| views.hides(&b.triangles(), true))
                })
                .collect()
        }),
    };
    let exposed_boxes = voxel_boxes.len() - candidates.len();
    let (quads, quads_found) = if use_shape(Shape::Quads) {
        let quads = timings.time("quads", || {
            // A closed surface's crossings decide exactly. An open one's winding number varies
            // away from the surface, so its inner voxels decide: those that no camera sees
            // through an opening. The exposure test then checks each quad. cpsv decides by
            // cells, so its inner voxels decide too.
            let closed = topology.boundary.is_empty();
            let inside = |p: DVec3| match cook.inside {
                InsideMethod::Winding if closed => field.crossings_above(p).0 >= 1,
                InsideMethod::Parity if closed => field.crossings_above(p).1 % 2 == 1,
                _ => grid.containing(p).is_some_and(|i| inner[i]),
            };
            quads::find(&mesh, cook.quad_grid, &inside)
        });
        let found = quads.len();
        let kept: Vec<Panel> = match &open_views {
            None => quads,
            Some(views) => timings.time("exposure-quads", || {
                quads
                    .into_par_iter()
                    .filter(|q| views.hides(&q.triangles(), false))
                    .collect()
            }),
        };
        (kept, found)
    } else {
        (Vec::new(), 0)
    };
    let exposed_quads = quads_found - quads.len();
    let quad_count = quads.len();
    let mut panels = quads;
    if use_shape(Shape::Patches) {
        let (lo, hi) = mesh.bounds();
        let size = f64::from((hi - lo).max_element());
        panels.extend(timings.time("patches", || {
            patches::find(
                &mesh,
                &topology.open_triangles,
                size / cook.quad_grid as f64,
                cook.min_patch_area * size * size,
            )
        }));
    }
    // Selection merges as it goes; its last merge is the solid part of the occluder.
    let selection = timings.time("select+merge", || {
        select::select(
            &mesh,
            &candidates,
            &panels,
            cook.max_triangles,
            cook.min_silhouette_gain,
        )
    });
    let occluder = Occluder {
        solid: selection.solid,
        panels: selection.panels.iter().map(|&i| panels[i]).collect(),
    };
    let kept = selection.boxes;
    if exposed_voxels + exposed_boxes + exposed_quads > 0 {
        notes.push(format!(
            "left out {exposed_voxels} voxels, {exposed_boxes} boxes and {exposed_quads} quads that show through an opening from above the horizon"
        ));
    }
    if inner_count == 0 && use_shape(Shape::Boxes) {
        notes.push(format!(
            "no inner voxels at resolution {}: the mesh encloses no volume thicker than a voxel, so no box fits",
            cook.resolution
        ));
    }
    if occluder.triangles() == 0 {
        notes.push("the occluder is empty: no piece added enough silhouette within the triangle budget".into());
    }
    if with_eval && gpu.is_some() && settings.eval.view_set == crate::eval::ViewSet::Outside {
        gpu_stages.push("eval");
    }
    let quality = match with_eval {
        false => None,
        true => Some(timings.time("eval", || {
            evaluate(
                &mesh,
                &topology.boundary,
                &occluder.mesh(),
                &settings.eval,
                gpu.as_deref(),
            )
        })?),
    };
    let kept_voxels: usize = kept.iter().map(|&i| voxel_boxes[i].voxels()).sum();
    let report = Report {
        pipeline_version: PIPELINE_VERSION,
        key,
        input: InputReport {
            triangles: mesh.triangles.len(),
            ingest,
            topology,
        },
        voxels: VoxelReport {
            surface: surface.iter().filter(|&&v| v).count(),
            solid: solid.iter().filter(|&&v| v).count(),
            inner: inner_count,
            exposed: exposed_voxels,
            cpsv: classified.cpsv,
        },
        grid,
        boxes: BoxReport {
            candidates: candidates.len() + exposed_boxes,
            exposed: exposed_boxes,
            kept: kept.len(),
            inner_volume_covered: if inner_count > 0 {
                kept_voxels as f64 / inner_count as f64
            } else {
                0.0
            },
            kept_boxes: kept.iter().map(|&i| candidates[i]).collect(),
        },
        panels: PanelReport {
            quad_candidates: quads_found,
            patch_candidates: panels.len() - quad_count,
            exposed: exposed_quads,
            kept_panels: occluder.panels.clone(),
        },
        occluder: OccluderReport {
            triangles: occluder.triangles(),
            vertices: occluder.solid.positions.len() + 4 * occluder.panels.len(),
            boxes: kept.len(),
            quads: occluder.panels.iter().filter(|p| p.shape == Shape::Quads).count(),
            patches: occluder.panels.iter().filter(|p| p.shape == Shape::Patches).count(),
            silhouette_gains: selection.gains,
        },
        device: gpu.as_ref().map_or("cpu".into(), |g| g.name()),
        gpu_stages,
        timings_ms: timings.timings,
        device_timings_ms: timings.device_timings,
        quality,
        notes,
    };
    Ok(Cooked { occluder, report })
}
