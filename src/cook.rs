//! One mesh through the whole pipeline: orient, find the surface pieces (and stop there when
//! they alone cover the silhouette), voxelize, classify, expand boxes, refine, find quads and
//! patches, select by silhouette, merge, and optionally evaluate.
//!
//! [`cook_with_progress`], `cook_closed`, `cook_voxels` and `select_and_finish` are the list of
//! stages; each is a function from named inputs to a named output, and `Run` times it, reports
//! its progress and, for a stage with a GPU twin, falls back to the CPU where the device cannot
//! do it.

mod report;

pub use report::{BoxReport, Cooked, InputReport, OccluderReport, PanelReport, Report, Timings, VoxelReport};

use crate::config::{CookSettings, Settings};
use crate::eval::{Quality, evaluate};
use crate::geom::openings::{Opening, close_openings};
use crate::geom::{f32_slack, raster};
use crate::gpu::{self, Gpu, GpuError};
use crate::key::{PIPELINE_VERSION, cache_key};
use crate::mesh::{IngestStats, Mesh, Topology, topology::orient_closed_components};
use crate::occluder::boxes::{self, VoxelBox};
use crate::occluder::exposure::OpenViews;
use crate::occluder::select::Silhouettes;
use crate::occluder::{
    Occluder, Panel, Shape, SurfacePiece, WorldBox, panel_mesh, patches, quads, refine, select, surface_pieces,
};
use crate::voxel::{self, Grid, InsideMethod, cpsv::CpsvStats, winding::WindingField};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// The stages of a cook, in order, for progress reports.
pub const STAGES: [&str; 20] = [
    "ingest",
    "orient",
    "openings",
    "surface-pieces",
    "key",
    "device",
    "surface",
    "inside",
    "inner",
    "exposure-render",
    "exposure-voxels",
    "boxes",
    "refine",
    "exposure-boxes",
    "silhouettes",
    "quads",
    "exposure-quads",
    "patches",
    "select+merge",
    "eval",
];

/// The stage this process started last, as an index into [`STAGES`]: what a panic names.
static LAST_STAGE: AtomicUsize = AtomicUsize::new(usize::MAX);

/// Records that `stage` (one of [`STAGES`]) has started, for [`last_stage`].
pub fn mark_stage(stage: &str) {
    if let Some(i) = STAGES.iter().position(|s| *s == stage) {
        LAST_STAGE.store(i, Ordering::Relaxed);
    }
}

/// The stage this process started last, if any.
pub fn last_stage() -> Option<&'static str> {
    STAGES.get(LAST_STAGE.load(Ordering::Relaxed)).copied()
}

/// Told each stage as it starts, with the share of the stages done (0..1). An error stops the
/// cook there, with the error's text as the reason (a time limit, a cancelled job).
pub type Progress<'a> = &'a (dyn Fn(&str, f64) -> Result<(), String> + Sync);

/// Why a cook did not finish.
#[derive(Debug, thiserror::Error)]
pub enum CookError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Its caller stopped it, as a stage was about to start.
    #[error("stopped before stage `{stage}`: {reason}")]
    Stopped { stage: String, reason: String },
}

/// Cooks an ingested mesh. `ingest_ms` is the time the caller spent reading it. Fails only when
/// the GPU it was told to use is missing or fails.
pub fn cook(
    mesh: Mesh,
    ingest: IngestStats,
    ingest_ms: f64,
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, CookError> {
    cook_with_progress(mesh, ingest, ingest_ms, settings, with_eval, &|_, _| Ok(()))
}

/// [`cook`], telling `progress` each stage as it starts.
pub fn cook_with_progress(
    mut mesh: Mesh,
    ingest: IngestStats,
    ingest_ms: f64,
    settings: &Settings,
    with_eval: bool,
    progress: Progress,
) -> Result<Cooked, CookError> {
    let cook = &settings.cook;
    let mut run = Run::new(ingest_ms, progress);
    // The key is of the mesh as given, which orient changes: of a copy, beside the stages that
    // are mostly serial, and dropped once the key is found.
    let given = mesh.clone();
    let ((topology, input, openings, ahead), (key, key_ms)) = run.beside(
        move || cache_key(&given, cook),
        |run| {
            let given_triangles = mesh.triangles.len();
            let mut topology = run.stage("orient", || orient_closed_components(&mut mesh))?;
            run.note_duplicates(topology.duplicate_triangles);
            let input = InputReport::new(given_triangles, ingest, &topology);
            let openings = run.close_openings(&mut mesh, &mut topology, cook.smallest_hole)?;
            let ahead = match closed_quads(&topology, cook) {
                Some(solid) => Ahead::Quads(solid),
                None => Ahead::Pieces(surface_pieces_of(run, &mesh, &topology, cook)?),
            };
            Ok((topology, input, openings, ahead))
        },
    )?;
    let prepared = Prepared {
        mesh,
        topology,
        key,
        input,
        openings,
    };
    let (pieces, silhouettes) = match ahead {
        Ahead::Quads(solid) => return cook_closed(run, &prepared, key_ms, solid, settings, with_eval),
        Ahead::Pieces(pieces) => pieces,
    };
    run.heard("key", key_ms)?;
    // A GPU asked for must be there, even where the surface alone makes the occluder.
    if cook.device == gpu::DeviceChoice::Gpu {
        run.open_device(cook.device, None)?;
    }
    // Low-poly and flat-shaded open art: its own surface may leave the voxel stages, and their
    // costly exposure test, nothing to add. A closed mesh has no exposure test, and its in-solid
    // quads sit behind its surface, where a runtime can cull what touches the wall's far side.
    let alone = silhouettes
        .as_ref()
        .filter(|_| could_be_enough(&pieces, cook.max_triangles))
        .map(|(found, _)| {
            // Their selection, part of the surface pieces' stage: progress has heard the key.
            run.more_of("surface-pieces", || {
                select_pieces(found, &prepared.mesh, &[], &[], &pieces, cook)
            })
        })
        .filter(|(_, chosen)| chosen.covered >= cook.surface_enough);
    match alone {
        Some((occluder, chosen)) => {
            if let Some((_, ms)) = silhouettes {
                run.heard("silhouettes", ms)?;
            }
            run.note_surface_alone(chosen.covered, cook.surface_enough);
            let parts = VoxelParts::skipped(fit_grid(&prepared.mesh, cook.resolution));
            finish(run, &prepared, parts, (occluder, chosen), settings, with_eval)
        }
        None => cook_voxels(run, &prepared, pieces, silhouettes, settings, with_eval),
    }
}

/// What a cook finds beside its key, once the mesh is oriented.
enum Ahead {
    /// Nothing yet: a closed mesh's quads, which its own crossings decide, are found beside
    /// everything else up to the selection, the surface pieces included ([`cook_closed`]).
    Quads(quads::Solid<'static>),
    /// The surface pieces, with an open mesh's silhouettes.
    Pieces(SurfacePieces),
}

/// The surface pieces, and the silhouettes drawn beside them, with their milliseconds.
type SurfacePieces = (Vec<SurfacePiece>, Option<(Silhouettes, f64)>);

/// Finds the surface pieces, and an open mesh's silhouettes beside them: whichever way an open
/// mesh goes, its selection weighs pieces against the same silhouettes, and the pieces are
/// found mostly serially.
fn surface_pieces_of(
    run: &mut Run,
    mesh: &Mesh,
    topology: &Topology,
    cook: &CookSettings,
) -> Result<SurfacePieces, CookError> {
    let find_pieces = |run: &mut Run| {
        run.kind_stage(cook.shapes.contains(&Shape::Surface), "surface-pieces", || {
            find_surface_pieces(mesh, topology)
        })
    };
    match topology.boundary.is_empty() {
        true => Ok((find_pieces(run)?, None)),
        false => {
            let (pieces, found) = run.beside(|| Silhouettes::new(mesh, &topology.open_triangles), find_pieces)?;
            Ok((pieces, Some(found)))
        }
    }
}

/// Least share of the surface's area that the pieces fitting in the budget must hold before
/// they are tried alone. Double-sided pieces covering a convex surface from every side hold at
/// least half of it; most meshes below this are curved, and their pieces would cover little.
const SURFACE_ALONE_AREA: f64 = 0.5;

/// Whether the largest pieces for their triangles that fit in the budget hold enough of the
/// surface's area to be worth a selection among them alone.
fn could_be_enough(pieces: &[SurfacePiece], max_triangles: usize) -> bool {
    let density = |p: &SurfacePiece| p.area / p.triangles.len().max(1) as f64;
    // Densest first, those as dense in the pieces' order: keys sorted, not the pieces.
    let mut densest: Vec<(f64, usize)> = pieces.iter().map(density).zip(0..).collect();
    densest.par_sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let (mut triangles, mut held) = (0, 0.0);
    for p in densest.into_iter().map(|(_, i)| &pieces[i]) {
        if triangles + p.triangles.len() <= max_triangles {
            triangles += p.triangles.len();
            held += p.area;
        }
    }
    let total: f64 = pieces.iter().map(|p| p.area).sum();
    total > 0.0 && held >= SURFACE_ALONE_AREA * total
}

/// The mesh ready for the voxel stages, and what the stages before them found for the report.
struct Prepared {
    mesh: Mesh,
    topology: Topology,
    key: String,
    input: InputReport,
    openings: Vec<Opening>,
}

/// What the voxel stages found, for the report.
struct VoxelParts {
    grid: Grid,
    voxels: VoxelReport,
    boxes: BoxReport,
    /// Quads found, then those dropped and cut as they showed through an opening.
    quads: (usize, [usize; 2]),
    /// Quads and patches the selection weighed.
    panels: usize,
}

impl VoxelParts {
    /// For a cook whose voxel stages did not run.
    fn skipped(grid: Grid) -> VoxelParts {
        VoxelParts {
            grid,
            voxels: VoxelReport::default(),
            boxes: BoxReport::default(),
            quads: (0, [0, 0]),
            panels: 0,
        }
    }
}

/// A closed mesh's cook with quads: the surface pieces and the voxel stages beside the quads.
fn cook_closed(
    mut run: Run,
    prepared: &Prepared,
    key_ms: f64,
    solid: quads::Solid<'static>,
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, CookError> {
    let cook = &settings.cook;
    let (mesh, topology) = (&prepared.mesh, &prepared.topology);
    let grid = fit_grid(mesh, cook.resolution);
    let ((pieces, voxels), (quads, ms)) = run.beside(
        || quads::find(mesh, cook.quad_grid, solid),
        |run| {
            let (pieces, _) = surface_pieces_of(run, mesh, topology, cook)?;
            run.heard("key", key_ms)?;
            run.open_device(cook.device, Some(cook_size(prepared, &grid)))?;
            Ok((pieces, voxel_stages(run, prepared, &grid, None, cook)?))
        },
    )?;
    run.heard("quads", ms)?;
    let found = Found {
        grid,
        pieces,
        voxels,
        quads,
        patches: None,
    };
    select_and_finish(run, prepared, found, settings, with_eval)
}

/// The voxel stages, with the patches beside them, then the quads their inner voxels hold.
fn cook_voxels(
    mut run: Run,
    prepared: &Prepared,
    pieces: Vec<SurfacePiece>,
    silhouettes: Option<(Silhouettes, f64)>,
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, CookError> {
    let cook = &settings.cook;
    let uses = |shape: Shape| cook.shapes.contains(&shape);
    let (mesh, topology) = (&prepared.mesh, &prepared.topology);
    let grid = fit_grid(mesh, cook.resolution);
    run.open_device(cook.device, Some(cook_size(prepared, &grid)))?;
    let (voxels, (patches, ms)) = run.beside(
        || uses(Shape::Patches).then(|| find_patches(mesh, topology, cook)),
        |run| voxel_stages(run, prepared, &grid, silhouettes, cook),
    )?;
    let quads = run.kind_stage(uses(Shape::Quads), "quads", || {
        find_quads(mesh, &grid, &voxels.inner, cook)
    })?;
    let found = Found {
        grid,
        pieces,
        voxels,
        quads,
        patches: patches.map(|patches| (patches, ms)),
    };
    select_and_finish(run, prepared, found, settings, with_eval)
}

/// The size of a cook's voxel stages, which decides where they run.
fn cook_size(prepared: &Prepared, grid: &Grid) -> gpu::CookSize {
    gpu::CookSize {
        voxels: grid.len(),
        triangles: prepared.mesh.triangles.len(),
        open: !prepared.topology.boundary.is_empty(),
    }
}

/// What the stages before the selection found: on the voxel grid, the surface pieces, the voxel
/// stages' parts, the quads, and the patches found beside them, with their milliseconds.
struct Found {
    grid: Grid,
    pieces: Vec<SurfacePiece>,
    voxels: VoxelStages,
    quads: Vec<Panel>,
    patches: Option<(Vec<Panel>, f64)>,
}

/// The selection over everything found, then the report.
fn select_and_finish(
    mut run: Run,
    prepared: &Prepared,
    found: Found,
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, CookError> {
    let Found {
        grid,
        pieces,
        voxels,
        quads: quads_found,
        patches: patches_found,
    } = found;
    let (mesh, topology, cook) = (&prepared.mesh, &prepared.topology, &settings.cook);
    let uses = |shape: Shape| cook.shapes.contains(&shape);
    let quad_count = quads_found.len();
    let (mut panels, quads_shown) = match &voxels.open_views {
        None => (quads_found, [0, 0]),
        Some(views) => run.stage("exposure-quads", || unexposed_quads(views, quads_found))?,
    };
    panels.extend(match patches_found {
        Some((patches, ms)) => {
            run.heard("patches", ms)?;
            patches
        }
        None => run.kind_stage(uses(Shape::Patches), "patches", || find_patches(mesh, topology, cook))?,
    });
    // Selection merges as it goes; its last merge is the solid part of the occluder.
    let (occluder, chosen) = run.stage("select+merge", || {
        select_pieces(
            &voxels.silhouettes,
            mesh,
            &voxels.box_candidates,
            &panels,
            &pieces,
            cook,
        )
    })?;
    let inner_count = voxels.inner.iter().filter(|&&v| v).count();
    let exposed = [voxels.exposed_voxels, voxels.exposed_boxes, quads_shown[0]];
    run.note_exposure(voxels.open_views.as_ref().map_or(0, OpenViews::cracks), quads_shown[1]);
    let no_box_fits = inner_count == 0 && uses(Shape::Boxes);
    run.note_outcome(exposed, no_box_fits, cook.resolution, (mesh, &occluder));
    let parts = VoxelParts {
        voxels: VoxelReport::new(&voxels.surface, &voxels.inside, inner_count, voxels.exposed_voxels),
        boxes: BoxReport::new(
            &voxels.voxel_boxes,
            &voxels.box_candidates,
            &voxels.box_sources,
            &chosen.boxes,
            [inner_count, voxels.exposed_boxes],
        ),
        grid,
        quads: (quad_count, quads_shown),
        panels: panels.len(),
    };
    finish(run, prepared, parts, (occluder, chosen), settings, with_eval)
}

/// What the voxel stages found: the voxels, the open views of an open mesh, and the boxes.
struct VoxelStages {
    surface: Vec<bool>,
    inside: voxel::Classified,
    /// Inner voxels no camera sees through an opening.
    inner: Vec<bool>,
    open_views: Option<OpenViews>,
    exposed_voxels: usize,
    /// Boxes an opening shows, even on the grid.
    exposed_boxes: usize,
    voxel_boxes: Vec<VoxelBox>,
    /// Each box candidate with the index of the voxel box it came from.
    box_sources: Vec<usize>,
    box_candidates: Vec<WorldBox>,
    silhouettes: Silhouettes,
}

/// Voxelize, classify, remove what an opening shows, and grow and refine the boxes; then the
/// selection's silhouettes, unless they were drawn beside the surface pieces (an open mesh's,
/// with the milliseconds they took, reported here in their place).
fn voxel_stages(
    run: &mut Run,
    prepared: &Prepared,
    grid: &Grid,
    silhouettes: Option<(Silhouettes, f64)>,
    cook: &CookSettings,
) -> Result<VoxelStages, CookError> {
    let uses = |shape: Shape| cook.shapes.contains(&shape);
    let (mesh, topology) = (&prepared.mesh, &prepared.topology);
    let surface = run.on_device("surface", |gpu| voxel::surface(mesh, grid, gpu))?;
    let inside = run.on_device("inside", |gpu| {
        voxel::classify(cook.inside, mesh, topology, grid, &surface, &cook.cpsv(), gpu)
    })?;
    run.note_undecided(inside.cpsv.as_ref());
    let mut inner = run.stage("inner", || inner_voxels(&inside.solid, &surface))?;
    // Built by the first stage that needs it.
    let field = OnceLock::new();
    let winding_field = || field.get_or_init(|| WindingField::new(mesh, &topology.boundary));
    // Only open meshes can show their inside.
    let open_views = match topology.boundary.is_empty() {
        true => None,
        false => Some(run.on_device("exposure-render", |gpu| {
            OpenViews::new(mesh, &topology.boundary, winding_field, gpu, (grid, &inner))
        })?),
    };
    let exposed_voxels = match &open_views {
        None => 0,
        Some(views) => run.on_device("exposure-voxels", |gpu| views.remove_exposed(grid, &mut inner, gpu))?,
    };
    let voxel_boxes = run.kind_stage(uses(Shape::Boxes), "boxes", || {
        boxes::expand(&inner, grid.dims, &expansion(cook))
    })?;
    let refined = run.stage("refine", || {
        let open = open_views.is_some();
        refine_boxes(
            mesh,
            grid,
            winding_field(),
            &inside.solid,
            &voxel_boxes,
            cook.refine,
            open,
        )
    })?;
    let kept = refined.len();
    let (box_sources, box_candidates): (Vec<usize>, Vec<WorldBox>) = match &open_views {
        None => refined.into_iter().map(|(id, refined, _)| (id, refined)).unzip(),
        Some(views) => run.stage("exposure-boxes", || unexposed_boxes(views, refined))?,
    };
    let exposed_boxes = kept - box_candidates.len();
    let silhouettes = match silhouettes {
        Some((found, ms)) => {
            run.heard("silhouettes", ms)?;
            found
        }
        None => run.stage("silhouettes", || Silhouettes::new(mesh, &topology.open_triangles))?,
    };
    Ok(VoxelStages {
        surface,
        inside,
        inner,
        open_views,
        exposed_voxels,
        exposed_boxes,
        voxel_boxes,
        box_sources,
        box_candidates,
        silhouettes,
    })
}

/// Evaluates the occluder when asked, and writes the report.
fn finish(
    mut run: Run,
    prepared: &Prepared,
    parts: VoxelParts,
    (occluder, chosen): (Occluder, Chosen),
    settings: &Settings,
    with_eval: bool,
) -> Result<Cooked, CookError> {
    let cook_ms = run.wall_ms();
    let quality = with_eval
        .then(|| run.evaluate(&prepared.mesh, &prepared.topology, &occluder, settings))
        .transpose()?;
    let report = Report {
        voxels: parts.voxels,
        boxes: parts.boxes,
        panels: PanelReport::new(
            parts.quads.0,
            parts.quads.1,
            parts.panels,
            chosen.piece_candidates,
            &occluder,
        ),
        occluder: OccluderReport::new(&occluder, chosen.boxes.len(), chosen.gains),
        input: prepared.input.clone(),
        openings_closed: prepared.openings.clone(),
        pipeline_version: PIPELINE_VERSION,
        key: prepared.key.clone(),
        grid: parts.grid,
        device: run.device_name(),
        gpu_stages: run.gpu_stages,
        timings_ms: run.timings,
        cook_ms,
        device_timings_ms: run.device_timings,
        quality,
        notes: run.notes,
    };
    Ok(Cooked { occluder, report })
}

/// The voxel grid over the mesh's bounds.
fn fit_grid(mesh: &Mesh, resolution: usize) -> Grid {
    let (lo, hi) = mesh.bounds();
    Grid::fit(lo, hi, resolution)
}

/// Solid voxels that no triangle touches.
fn inner_voxels(solid: &[bool], surface: &[bool]) -> Vec<bool> {
    solid.par_iter().zip(surface).map(|(&s, &t)| s && !t).collect()
}

fn expansion(cook: &CookSettings) -> boxes::ExpansionSettings {
    boxes::ExpansionSettings {
        target_coverage: cook.target_coverage,
        min_box_gain: cook.min_box_gain,
        max_boxes: cook.max_boxes,
        min_box_voxels: cook.min_box_voxels,
    }
}

/// Each box with its index, its faces pushed up to the surface (when `refine`), and on the grid.
/// Where writing them as f32 may move a corner ([`Grid::f32_slack`]), as a face on the grid may
/// touch the surface, both are rounded inwards to what f32 holds, those of an open mesh after
/// shrinking by that much, as its exposure test draws in f32; boxes that vanish are left out.
fn refine_boxes(
    mesh: &Mesh,
    grid: &Grid,
    field: &WindingField,
    solid: &[bool],
    voxel_boxes: &[VoxelBox],
    refine: bool,
    open: bool,
) -> Vec<(usize, WorldBox, WorldBox)> {
    let mut owner = vec![u32::MAX; grid.len()];
    for (id, b) in voxel_boxes.iter().enumerate() {
        for x in b.lo[0]..b.hi[0] {
            for y in b.lo[1]..b.hi[1] {
                owner[grid.index(x, y, b.lo[2])..grid.index(x, y, b.hi[2])].fill(id as u32);
            }
        }
    }
    let slack = grid.f32_slack();
    let exact = |b: WorldBox| match slack > 0.0 {
        true => b.rounded_inward(if open { slack } else { 0.0 }),
        false => Some(b),
    };
    let input = refine::RefineInput {
        mesh,
        grid,
        field,
        solid,
        owner: &owner,
    };
    voxel_boxes
        .iter()
        .enumerate()
        .filter_map(|(id, b)| {
            let on_grid = WorldBox::from_voxels(grid, b);
            let refined = refine.then(|| refine::refine(&input, id as u32, b));
            Some((id, exact(refined.unwrap_or(on_grid))?, exact(on_grid)?))
        })
        .collect()
}

/// Near an opening a refined face can reach past the solid; such a box falls back to its
/// voxels, and is dropped if even those show. Each box kept comes with the index of the voxel
/// box it came from.
fn unexposed_boxes(views: &OpenViews, candidates: Vec<(usize, WorldBox, WorldBox)>) -> (Vec<usize>, Vec<WorldBox>) {
    candidates
        .into_par_iter()
        .filter_map(|(i, refined, on_grid)| {
            [refined, on_grid]
                .into_iter()
                .find(|b| views.hides_box(&b.triangles()))
                .map(|b| (i, b))
        })
        .unzip()
}

/// A closed surface's crossings decide exactly whether a quad lies inside, under winding or
/// parity. None where the voxels decide ([`find_quads`]) or no quads are asked for.
fn closed_quads(topology: &Topology, cook: &CookSettings) -> Option<quads::Solid<'static>> {
    match cook.inside {
        InsideMethod::Winding | InsideMethod::Parity
            if topology.boundary.is_empty() && cook.shapes.contains(&Shape::Quads) =>
        {
            Some(quads::Solid::Closed {
                parity: cook.inside == InsideMethod::Parity,
            })
        }
        _ => None,
    }
}

/// An open surface's winding number varies away from the surface, so its inner voxels decide
/// whether a quad lies inside: those that no camera sees through an opening. The exposure test
/// then checks each quad. cpsv decides by cells, so its inner voxels decide too.
fn find_quads(mesh: &Mesh, grid: &Grid, inner: &[bool], cook: &CookSettings) -> Vec<Panel> {
    let inner_voxel = |p: DVec3| grid.containing(p).is_some_and(|i| inner[i]);
    // The inner voxels as runs along z: few boxes where the quads may lie.
    let [_, ny, nz] = grid.dims;
    let mut runs = Vec::new();
    for (column, cells) in inner.chunks(nz).enumerate() {
        let (x, y) = (column / ny, column % ny);
        let mut z = 0;
        while let Some(start) = cells[z..].iter().position(|&i| i).map(|k| z + k) {
            let end = cells[start..].iter().position(|&i| !i).map_or(nz, |k| start + k);
            let run = VoxelBox {
                lo: [x, y, start],
                hi: [x + 1, y + 1, end],
            };
            runs.push(WorldBox::from_voxels(grid, &run));
            z = end;
        }
    }
    let solid = quads::Solid::Points {
        at: &inner_voxel,
        within: &runs,
    };
    quads::find(mesh, cook.quad_grid, solid)
}

/// The quads no view sees; one that shows in part is cut down to its largest hidden rectangle.
/// Also returns how many were dropped and how many cut.
fn unexposed_quads(views: &OpenViews, quads: Vec<Panel>) -> (Vec<Panel>, [usize; 2]) {
    let found = quads.len();
    let kept: Vec<(Panel, bool)> = quads
        .into_par_iter()
        .filter_map(|q| match views.hides_panel(&q) {
            true => Some((q, false)),
            false => views.hidden_part(&q).map(|part| (part, true)),
        })
        .collect();
    let cut = kept.iter().filter(|(_, cut)| *cut).count();
    let dropped = found - kept.len();
    (kept.into_iter().map(|(q, _)| q).collect(), [dropped, cut])
}

/// None where the mesh lies so far from the origin that writing a patch as f32 may move it off
/// the surface it lies on ([`f32_slack`]).
fn find_patches(mesh: &Mesh, topology: &Topology, cook: &CookSettings) -> Vec<Panel> {
    let (lo, hi) = mesh.bounds();
    if f32_slack(lo.as_dvec3(), hi.as_dvec3()) > 0.0 {
        return Vec::new();
    }
    let size = f64::from((hi - lo).max_element());
    patches::find(
        mesh,
        &topology.open_triangles,
        size / cook.quad_grid as f64,
        cook.min_patch_area * size * size,
    )
}

/// Most surface pieces the selection weighs, largest first.
const MAX_SURFACE_PIECES: usize = 1024;

/// The flat regions of the mesh as pieces: corners within a tenth of the evaluation's depth
/// tolerance (1e-4 of the bounding sphere's diameter) of their region's plane.
fn find_surface_pieces(mesh: &Mesh, topology: &Topology) -> Vec<SurfacePiece> {
    let (_, radius) = mesh.bounding_sphere();
    surface_pieces::find(mesh, &topology.open_triangles, 2e-5 * radius)
}

/// What the selection chose, with the occluder built from it.
struct Chosen {
    boxes: Vec<usize>,
    gains: Vec<f64>,
    /// Silhouette share covered, at the selection's views.
    covered: f64,
    /// Surface pieces it weighed.
    piece_candidates: usize,
}

/// The pieces that add the most silhouette within the triangle budget, the boxes merged. Surface
/// pieces smaller than half a patch a triangle are not worth their triangles. When all of the
/// surface, as pieces, fits in the budget, it is the occluder if what it adds over the selection
/// is worth its extra triangles at the selection's own price (a patch's two triangles for
/// `min_silhouette_gain`): it hides exactly what the mesh hides.
fn select_pieces(
    silhouettes: &Silhouettes,
    mesh: &Mesh,
    boxes: &[WorldBox],
    panels: &[Panel],
    pieces: &[SurfacePiece],
    cook: &CookSettings,
) -> (Occluder, Chosen) {
    let (lo, hi) = mesh.bounds();
    let size = f64::from((hi - lo).max_element());
    let worth = |p: &&SurfacePiece| p.area >= 0.5 * cook.min_patch_area * size * size * p.triangles.len() as f64;
    let weighed: Vec<&SurfacePiece> = pieces.iter().filter(worth).take(MAX_SURFACE_PIECES).collect();
    let sheets: Vec<Mesh> = panels
        .iter()
        .map(|p| panel_mesh(std::slice::from_ref(p)))
        .chain(weighed.iter().map(|p| p.mesh()))
        .collect();
    let selection = select::select(
        silhouettes,
        boxes,
        &sheets,
        cook.max_triangles,
        (cook.min_silhouette_gain, cook.min_silhouette_own),
    );
    let whole_triangles: usize = pieces.iter().map(|p| p.triangles.len()).sum();
    let missed = 1.0 - selection.covered;
    let extra = whole_triangles.saturating_sub(selection.triangles);
    let worth_it = missed >= cook.min_silhouette_gain * (extra.max(2) as f64 / 2.0);
    if !pieces.is_empty() && whole_triangles <= cook.max_triangles && worth_it {
        let chosen = Chosen {
            boxes: Vec::new(),
            gains: vec![1.0],
            covered: 1.0,
            piece_candidates: weighed.len(),
        };
        let occluder = Occluder {
            pieces: pieces.to_vec(),
            ..Occluder::default()
        };
        return (occluder, chosen);
    }
    let (chosen_panels, chosen_pieces): (Vec<usize>, Vec<usize>) =
        selection.sheets.iter().partition(|&&i| i < panels.len());
    let occluder = Occluder {
        solid: selection.solid,
        panels: chosen_panels.iter().map(|&i| panels[i]).collect(),
        pieces: chosen_pieces
            .iter()
            .map(|&i| SurfacePiece {
                double_sided: true,
                ..weighed[i - panels.len()].clone()
            })
            .collect(),
    };
    let chosen = Chosen {
        boxes: selection.boxes,
        gains: selection.gains,
        covered: selection.covered,
        piece_candidates: weighed.len(),
    };
    (occluder, chosen)
}

/// A cook under way: the stages' times and progress, the device they may use, and the notes
/// and GPU stages the report will name.
struct Run<'a> {
    timings: Timings,
    /// When the stages after ingest began.
    started: Instant,
    /// The device's own time per stage, where it has timestamp queries.
    device_timings: Timings,
    /// The timed device handle, once open.
    gpu: Option<Arc<Gpu>>,
    /// Whether the device choice was made (a CPU choice leaves `gpu` empty).
    device_chosen: bool,
    /// The stages that ran on that GPU.
    gpu_stages: Vec<&'static str>,
    /// Why the occluder is empty or smaller than asked, in words.
    notes: Vec<String>,
    progress: Progress<'a>,
}

impl<'a> Run<'a> {
    fn new(ingest_ms: f64, progress: Progress<'a>) -> Run<'a> {
        Run {
            timings: Timings(vec![("ingest".into(), ingest_ms)]),
            started: Instant::now(),
            device_timings: Timings::default(),
            gpu: None,
            device_chosen: false,
            gpu_stages: Vec::new(),
            notes: Vec::new(),
            progress,
        }
    }

    /// Wall-clock milliseconds of the cook so far, ingest included.
    fn wall_ms(&self) -> f64 {
        self.timings.get("ingest") + self.started.elapsed().as_secs_f64() * 1e3
    }

    /// Reports `stage` as it starts, unless the progress callback stops the cook there.
    fn start(&self, stage: &str) -> Result<(), CookError> {
        let done = STAGES.iter().position(|s| *s == stage).unwrap_or(0);
        mark_stage(stage);
        (self.progress)(stage, done as f64 / STAGES.len() as f64).map_err(|reason| CookError::Stopped {
            stage: stage.to_string(),
            reason,
        })
    }

    /// Runs `stage`, reporting it as it starts and timing it, unless the progress callback
    /// stops the cook there.
    fn stage<T>(&mut self, stage: &str, work: impl FnOnce() -> T) -> Result<T, CookError> {
        self.start(stage)?;
        let out = self.more_of(stage, work);
        match self.gpu.as_ref().map(|g| g.take_device_ms()) {
            Some(Ok(Some(ms))) if ms > 0.0 => self.device_timings.add(stage, ms),
            Some(Err(e)) => tracing::warn!(stage, "the device's pass times could not be read: {e}"),
            _ => {}
        }
        Ok(out)
    }

    /// Runs more of `stage`, which has started, timed as its own and named if it panics:
    /// progress hears nothing, as it may have heard the stages after.
    fn more_of<T>(&mut self, stage: &str, work: impl FnOnce() -> T) -> T {
        mark_stage(stage);
        let start = Instant::now();
        let out = work();
        self.timings.add(stage, start.elapsed().as_secs_f64() * 1e3);
        out
    }

    /// Runs `main` and, on another thread meanwhile, `beside`: a CPU stage that needs nothing
    /// `main` makes. Returns its result with the milliseconds it took, for [`Run::heard`] to
    /// report in its place in the order. Each stage is timed as it ran, so their times add up
    /// to more than the wall time, which the report gives as `cook_ms`.
    fn beside<A: Send, B: Send>(
        &mut self,
        beside: impl FnOnce() -> B + Send,
        main: impl FnOnce(&mut Self) -> Result<A, CookError> + Send,
    ) -> Result<(A, (B, f64)), CookError> {
        let (main, beside) = rayon::join(
            || main(self),
            || {
                let start = Instant::now();
                (beside(), start.elapsed().as_secs_f64() * 1e3)
            },
        );
        Ok((main?, beside))
    }

    /// Reports `stage`, run [`Run::beside`] others in `ms`, as starting now: progress hears of
    /// it in its place.
    fn heard(&mut self, stage: &str, ms: f64) -> Result<(), CookError> {
        self.start(stage)?;
        self.timings.add(stage, ms);
        Ok(())
    }

    /// A stage that finds pieces of one kind: none, and not run, when `cook.shapes` leaves that
    /// kind out.
    fn kind_stage<T>(&mut self, used: bool, stage: &str, work: impl FnOnce() -> Vec<T>) -> Result<Vec<T>, CookError> {
        match used {
            true => self.stage(stage, work),
            false => Ok(Vec::new()),
        }
    }

    /// Runs a stage with a GPU twin on the device when there is one; where the device cannot do
    /// it, on the CPU, with a note saying why.
    fn on_device<T>(
        &mut self,
        stage: &'static str,
        mut work: impl FnMut(Option<&Gpu>) -> Result<T, GpuError>,
    ) -> Result<T, CookError> {
        let gpu = self.gpu.clone();
        let (out, fallback) = self.stage(stage, || match work(gpu.as_deref()) {
            Err(GpuError::Unsupported(why)) if gpu.is_some() => (work(None), Some(why)),
            out => (out, None),
        })?;
        // A stage that found the CPU faster for its work ran no pass.
        let ran_passes = gpu.is_some_and(|gpu| gpu.take_passes() > 0);
        match fallback {
            Some(why) => self.notes.push(format!("{stage} ran on the CPU: {why}")),
            None if ran_passes => self.gpu_stages.push(stage),
            None => {}
        }
        Ok(out?)
    }

    /// Opens the device `choice` asks for, for a cook of `size` where given ([`gpu::for_cook`]);
    /// once a process. Builds the pipelines of the stages a cook runs there.
    fn open_device(&mut self, choice: gpu::DeviceChoice, size: Option<gpu::CookSize>) -> Result<(), CookError> {
        if self.device_chosen {
            return Ok(());
        }
        self.device_chosen = true;
        let placement = self.stage("device", || {
            let placement = match size {
                Some(size) => gpu::for_cook(choice, size)?,
                None => gpu::for_choice(choice)?,
            };
            if let Some(gpu) = &placement.gpu {
                gpu.build_pipelines(&PIPELINES.concat())?;
            }
            Ok::<_, GpuError>(placement)
        })??;
        let auto = choice == gpu::DeviceChoice::Auto;
        self.gpu = placement.gpu.map(|g| Arc::new(g.timed().where_it_pays(auto)));
        self.notes.extend(placement.why_cpu);
        Ok(())
    }

    /// Closes the openings of `mesh` narrower than `width` and orients it again, with a note.
    fn close_openings(
        &mut self,
        mesh: &mut Mesh,
        topology: &mut Topology,
        width: f64,
    ) -> Result<Vec<Opening>, CookError> {
        if width <= 0.0 || topology.boundary.is_empty() {
            return Ok(Vec::new());
        }
        let openings = self.stage("openings", || {
            let (closed, openings) = close_openings(mesh, &topology.boundary, width);
            *mesh = closed;
            *topology = orient_closed_components(mesh);
            openings
        })?;
        self.note_openings(&openings, width);
        Ok(openings)
    }

    fn note_openings(&mut self, openings: &[Opening], smallest_hole: f64) {
        if !openings.is_empty() {
            let count = |kind: &str| openings.iter().filter(|o| o.kind == kind).count();
            self.notes.push(format!(
                "{} openings narrower than smallest_hole {smallest_hole} count as closed ({} holes, {} gaps, {} seams): the occluder may hide what is seen through them, and eval judges against the mesh with them closed",
                openings.len(),
                count("hole"),
                count("gap"),
                count("seam")
            ));
        }
    }

    fn note_stray_vertex(&mut self, mesh: &Mesh) {
        if let Some(p) = mesh.stray_vertex() {
            self.notes.push(format!(
                "a vertex at ({:?}, {:?}, {:?}) lies far outside the rest of the mesh: the voxel grid spans the gap, \
                 so the rest is under a few voxels; a stray vertex from the export?",
                p.x, p.y, p.z
            ));
        }
    }

    fn note_duplicates(&mut self, duplicates: usize) {
        if duplicates > 0 {
            self.notes.push(format!(
                "left out {duplicates} copied triangles: every triangle of their parts had a copy on the same \
                 three corners, as faces copied for double-sided art do, so each part's volume counts once"
            ));
        }
    }

    fn note_surface_alone(&mut self, covered: f64, enough: f64) {
        self.notes.push(format!(
            "the surface pieces alone cover {:.1}% of the silhouette at the selection's views, at least \
             cook.surface_enough ({enough}): they are the occluder, and the voxel stages did not run",
            covered * 100.0
        ));
    }

    fn note_undecided(&mut self, cpsv: Option<&CpsvStats>) {
        if let Some(stats) = cpsv.filter(|s| s.undecided_cells > 0) {
            self.notes.push(format!(
                "cpsv left {} of {} cells ({} voxels) undecided; they count as outside",
                stats.undecided_cells, stats.cells, stats.undecided_voxels
            ));
        }
    }

    /// Notes on what the exposure test found beside openings: boundary edges along cracks,
    /// through which it looked, and quads that showed in part, cut down to what does not.
    fn note_exposure(&mut self, cracks: usize, cut_quads: usize) {
        if cracks > 0 {
            self.notes.push(format!(
                "{cracks} boundary edges run along cracks narrower than a pixel between parts: what shows through them counts as seen"
            ));
        }
        if cut_quads > 0 {
            self.notes.push(format!(
                "{cut_quads} quads showed through an opening in part and were cut down to the rest"
            ));
        }
    }

    /// Notes on what was left out, and on why the occluder of `mesh` may be empty or small (no
    /// inner voxels, or nothing at all, perhaps from a stray vertex): `exposed` counts the
    /// voxels, boxes and quads that show through an opening.
    fn note_outcome(
        &mut self,
        exposed: [usize; 3],
        no_inner_voxels: bool,
        resolution: usize,
        (mesh, occluder): (&Mesh, &Occluder),
    ) {
        let [voxels, boxes, quads] = exposed;
        if voxels + boxes + quads > 0 {
            self.notes.push(format!(
                "left out {voxels} voxels, {boxes} boxes and {quads} quads that show through an opening from above the horizon"
            ));
        }
        if no_inner_voxels {
            self.notes.push(format!(
                "no inner voxels at resolution {resolution}: the mesh encloses no volume thicker than a voxel, so no box fits"
            ));
        }
        let empty = occluder.triangles() == 0;
        if empty {
            self.notes
                .push("the occluder is empty: no piece added enough silhouette within the triangle budget, or kept enough of its own".into());
        }
        if no_inner_voxels || empty {
            self.note_stray_vertex(mesh);
        }
    }

    /// The quality figures; only the outside views are drawn on the GPU.
    fn evaluate(
        &mut self,
        mesh: &Mesh,
        topology: &Topology,
        occluder: &Occluder,
        settings: &Settings,
    ) -> Result<Quality, CookError> {
        if !settings.eval.draws_on_gpu() {
            return Ok(self.stage("eval", || {
                evaluate(mesh, &topology.boundary, &occluder.mesh(), &settings.eval, None)
            })??);
        }
        self.on_device("eval", |gpu| {
            evaluate(mesh, &topology.boundary, &occluder.mesh(), &settings.eval, gpu)
        })
    }

    /// What the report calls the device: "cpu", or the GPU adapter's name.
    fn device_name(&self) -> String {
        self.gpu.as_ref().map_or("cpu".into(), |g| g.name())
    }
}

/// The compute pipelines a cook may run, built when it opens the device so that no stage pays
/// for shader compilation.
const PIPELINES: [&[(&str, &str)]; 5] = [
    &voxel::surface::gpu::ENTRY_POINTS,
    &voxel::parity::gpu::ENTRY_POINTS,
    &voxel::winding::gpu::ENTRY_POINTS,
    &raster::gpu::ENTRY_POINTS,
    &crate::occluder::exposure::gpu::ENTRY_POINTS,
];

#[cfg(test)]
mod tests {
    use super::*;

    /// The stages heard, in order, as a cook of `mesh` reports them, with its report.
    fn heard_stages(mesh: Mesh) -> (Vec<String>, Report) {
        let settings = crate::config::load(None, &[]).expect("defaults load");
        let heard = std::sync::Mutex::new(Vec::new());
        let progress = |stage: &str, done: f64| {
            heard.lock().unwrap().push((stage.to_string(), done));
            Ok(())
        };
        let cooked = cook_with_progress(mesh, Default::default(), 2.0, &settings, false, &progress).expect("cooks");
        let heard = heard.into_inner().unwrap();
        assert!(heard.windows(2).all(|w| w[0].1 <= w[1].1), "{heard:?}");
        (heard.into_iter().map(|(stage, _)| stage).collect(), cooked.report)
    }

    fn in_order(stages: &[String], order: &[&str]) {
        let at = |stage: &str| stages.iter().position(|s| s == stage).expect(stage);
        assert!(order.windows(2).all(|w| at(w[0]) < at(w[1])), "{stages:?}");
    }

    #[test]
    fn quads_found_beside_the_surface_pieces_and_voxel_stages_are_reported_in_their_place() {
        let (stages, r) = heard_stages(crate::mesh::shapes::torus(1.0, 0.45, 32, 16));
        let order = [
            "orient",
            "surface-pieces",
            "key",
            "surface",
            "refine",
            "silhouettes",
            "quads",
            "select+merge",
        ];
        in_order(&stages, &order);
        assert!(r.occluder.quads > 0 && r.timings_ms.get("quads") > 0.0, "{r:?}");
        // Wall time: the ingest it was given, and the stages after.
        assert!(r.cook_ms > 2.0 && r.total_ms() == r.cook_ms, "{}", r.cook_ms);
    }

    #[test]
    fn the_key_found_beside_orient_is_of_the_mesh_as_given_and_heard_after_the_surface_pieces() {
        // Inside out: orient turns every triangle.
        let mut given = crate::mesh::shapes::torus(1.0, 0.45, 32, 16);
        given.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        let mut oriented = given.clone();
        orient_closed_components(&mut oriented);
        let cook = crate::config::load(None, &[]).expect("defaults load").cook;
        assert_ne!(cache_key(&given, &cook), cache_key(&oriented, &cook));
        let (stages, r) = heard_stages(given.clone());
        in_order(&stages, &["orient", "surface-pieces", "key", "surface"]);
        assert_eq!(r.key, cache_key(&given, &cook));
    }

    #[test]
    fn the_densest_pieces_as_dense_as_others_are_taken_in_the_pieces_order() {
        let piece = |triangles: usize, area: f64| SurfacePiece {
            triangles: vec![[[0.0; 3]; 3]; triangles],
            area,
            source_triangles: triangles,
            double_sided: false,
        };
        // Two as dense: the first taken fills the budget of two triangles (2 of 3.1 held), or
        // leaves room for the least dense only (1.1 held).
        let (a, b, least) = (piece(2, 2.0), piece(1, 1.0), piece(1, 0.1));
        assert!(could_be_enough(&[a.clone(), b.clone(), least.clone()], 2));
        assert!(!could_be_enough(&[b, a, least], 2));
    }

    #[test]
    fn an_open_meshs_patches_found_beside_the_voxel_stages_are_reported_in_their_place() {
        let mut open = crate::mesh::shapes::torus(1.0, 0.45, 32, 16);
        open.triangles.drain(0..4);
        let (stages, r) = heard_stages(open);
        let order = [
            "exposure-render",
            "silhouettes",
            "quads",
            "exposure-quads",
            "patches",
            "select+merge",
        ];
        in_order(&stages, &order);
        assert!(r.timings_ms.get("patches") > 0.0, "{r:?}");
    }

    #[test]
    fn an_open_mesh_whose_surface_pieces_alone_make_the_occluder_reports_its_stages_in_order() {
        // A unit box without its top: five flat pieces, ten triangles.
        let corner = |i: u32| glam::Vec3::new((i & 1) as f32, (i >> 1 & 1) as f32, (i >> 2 & 1) as f32);
        let faces = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [0, 2, 3, 1], [4, 5, 7, 6]];
        let open_box = Mesh {
            positions: (0..8).map(corner).collect(),
            triangles: faces.iter().flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]]).collect(),
        };
        let (stages, r) = heard_stages(open_box);
        assert!(
            r.notes.iter().any(|n| n.contains("surface pieces alone")),
            "{:?}",
            r.notes
        );
        assert!(!stages.iter().any(|s| s == "surface"), "{stages:?}");
        in_order(&stages, &["orient", "surface-pieces", "key", "silhouettes"]);
    }

    #[test]
    fn a_stage_is_listed_on_the_gpu_where_it_ran_passes_there_and_noted_where_refused() {
        let Some(gpu) = gpu::device_for_tests() else {
            return;
        };
        let mut run = Run::new(0.0, &|_, _| Ok(()));
        run.gpu = Some(Arc::new(gpu.timed()));
        let refused = run.on_device("exposure-voxels", |gpu| match gpu {
            Some(_) => Err(GpuError::Unsupported("too large for one binding".into())),
            None => Ok("cpu"),
        });
        assert_eq!(refused.unwrap(), "cpu");
        let mesh = Mesh {
            positions: vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        let grid = fit_grid(&mesh, 8);
        let ran = run.on_device("surface", |gpu| voxel::surface(&mesh, &grid, gpu));
        assert!(ran.unwrap().contains(&true));
        // Handed the device, this one found the CPU faster for its work: no pass ran there.
        let declined = run.on_device("exposure-render", |gpu| Ok(gpu.is_some()));
        assert!(declined.unwrap());
        assert_eq!(run.gpu_stages, ["surface"]);
        assert_eq!(run.notes, ["exposure-voxels ran on the CPU: too large for one binding"]);
    }
}
