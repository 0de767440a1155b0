//! A whole map as one soup: its flat surface pieces, chosen cell by cell by what they hide from
//! where players stand.
//!
//! 1. The map's surface goes into a bricked voxel grid ([`BrickGrid`], an effective 1024³ by
//!    default), where [`FreeSpace`] finds floors, and eye points at `level.eye_height` above them
//!    spread over the whole map.
//! 2. Its flat regions become surface pieces ([`surface_pieces::find`]), each cut to the cell
//!    (`level.soup_cell_size`) that holds its centre.
//! 3. In each cell, pieces are chosen greedily by the pixels they newly cover in cube maps from
//!    the eye points near the cell, per triangle, within `level.soup_triangle_share` of the
//!    cell's own triangles.
//!
//! Pieces lie on the map's surface, so they hide nothing that the map does not; they are drawn
//! from both sides.

use super::batch::{Placed, cluster};
use super::free_space::{FreeSpace, Pose};
use super::{Baked, BatchInfo, Level, LevelError, LevelReport};
use crate::config::{LevelSettings, Settings};
use crate::geom::camera::View;
use crate::geom::raster::rasterize;
use crate::gpu::Gpu;
use crate::key::cache_key;
use crate::mesh::{Mesh, weld_positions};
use crate::mesh::{glb, point_bounds};
use crate::occluder::surface_pieces::{self, SurfacePiece};
use crate::store::{ResultMeta, Store, job::now_ms};
use crate::voxel::bricks::{BrickGrid, BrickStats};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::time::Instant;

/// Eye points looked from, per cell holding pieces.
const EYES_PER_CELL: usize = 8;
/// Eye points at most, whatever the cells: each costs four views of every piece triangle, so
/// small cells (`level.soup_cell_size`) share these rather than cost hours. The default
/// cells (at most 8³) never reach it.
const MAX_EYES: usize = 4096;
/// Pixels along a side of each view the selection looks through.
const FACE_PIXELS: usize = 64;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SoupInfo {
    pub map_triangles: usize,
    /// Surface pieces found, and their triangles.
    pub pieces: usize,
    pub piece_triangles: usize,
    pub pieces_chosen: usize,
    /// Cells holding pieces.
    pub cells: usize,
    pub cell_size: f64,
    pub eye_height: f64,
    /// Eye points found on the map's floors.
    pub eye_points: usize,
    pub grid: BrickStats,
    /// Where the bricks were voxelized: the GPU adapter's name, or "cpu".
    pub bricks_device: String,
}

/// One cell's chosen pieces, as one double-sided mesh, with its bounds.
pub struct CellOccluder {
    pub mesh: Mesh,
    pub lo: DVec3,
    pub hi: DVec3,
}

/// Cooks `map`, its bricks on `gpu` when one is given: per cell, the pieces chosen; stage
/// times go to `timings`.
pub fn cook_soup(
    map: &Mesh,
    settings: &LevelSettings,
    gpu: Option<&Gpu>,
    timings: &mut crate::cook::Timings,
) -> Result<(Vec<CellOccluder>, SoupInfo), String> {
    let mut stage = Instant::now();
    let mut lap = |name: &str, timings: &mut crate::cook::Timings| {
        timings.0.push((name.into(), stage.elapsed().as_secs_f64() * 1e3));
        stage = Instant::now();
    };
    let map = welded(map);
    let (lo, hi) = map.bounds();
    let longest = f64::from((hi - lo).max_element()).max(1e-9);
    let voxel_size = match settings.voxel_size {
        0.0 => longest / 1024.0,
        size => size,
    };
    let cell_size = match settings.soup_cell_size {
        0.0 => longest / 8.0,
        size => size,
    };
    let grid = BrickGrid::voxelize(&map, voxel_size, gpu)?;
    lap("bricks", timings);
    let (_, radius) = map.bounding_sphere();
    let pieces = surface_pieces::find(&map, &vec![true; map.triangles.len()], 2e-5 * radius);
    lap("pieces", timings);
    let cells = by_cell(&pieces, cell_size);
    let eyes = FreeSpace::new(&grid, settings.eye_height).cameras((EYES_PER_CELL * cells.len()).min(MAX_EYES), 0x5eed);
    if eyes.is_empty() {
        return Err(format!(
            "no floor with room to stand at level.eye_height = {} (in the map's units): set it to a player's eye height",
            settings.eye_height
        ));
    }
    lap("eye points", timings);
    let seen = visible_pixels(&pieces, &eyes, longest);
    let budget = (settings.soup_triangle_share * map.triangles.len() as f64).floor() as usize;
    let picked = choose(&pieces, &cells, &seen, budget, settings.soup_cell_triangles);
    let chosen: Vec<CellOccluder> = picked
        .iter()
        .filter(|p| !p.is_empty())
        .map(|p| {
            let mesh = surface_pieces::pieces_mesh(p);
            let (lo, hi) = mesh.bounds();
            CellOccluder {
                mesh,
                lo: lo.as_dvec3(),
                hi: hi.as_dvec3(),
            }
        })
        .collect();
    lap("select", timings);
    let info = SoupInfo {
        map_triangles: map.triangles.len(),
        pieces: pieces.len(),
        piece_triangles: pieces.iter().map(|p| p.triangles.len()).sum(),
        pieces_chosen: picked.iter().map(Vec::len).sum(),
        cells: cells.len(),
        cell_size,
        eye_height: settings.eye_height,
        eye_points: eyes.len(),
        grid: grid.stats(),
        bricks_device: gpu.map_or("cpu".into(), Gpu::name),
    };
    Ok((chosen, info))
}

/// The map with corners at equal positions joined, so that flat regions run across the groups
/// it was read as.
fn welded(map: &Mesh) -> Mesh {
    let (positions, remap) = weld_positions(&map.positions);
    Mesh {
        positions,
        triangles: map.triangles.iter().map(|t| t.map(|v| remap[v as usize])).collect(),
    }
}

/// Pieces by the cell holding the centre of their bounds.
fn by_cell(pieces: &[SurfacePiece], cell_size: f64) -> BTreeMap<[i32; 3], Vec<usize>> {
    let mut cells: BTreeMap<[i32; 3], Vec<usize>> = BTreeMap::new();
    for (i, piece) in pieces.iter().enumerate() {
        let corners = piece.triangles.iter().flatten().map(|c| DVec3::from_array(*c));
        let (lo, hi) = point_bounds(corners);
        let cell = ((lo + hi) * 0.5 / cell_size).floor().as_ivec3().to_array();
        cells.entry(cell).or_default().push(i);
    }
    cells
}

/// For each triangle of each piece (in order), the pixels where it is the nearest surface, over
/// views as players see: the four sideways directions from each eye point, in the middle half
/// of each square view's rows (a 2:1 buffer, as a runtime's). What is seen often and large is
/// what hides the rest.
fn visible_pixels(pieces: &[SurfacePiece], eyes: &[Pose], longest: f64) -> Vec<u64> {
    let triangles: Vec<[DVec3; 3]> = pieces
        .iter()
        .flat_map(|p| p.triangles.iter().map(|t| t.map(DVec3::from_array)))
        .collect();
    let near = longest * 1e-7;
    let rows = FACE_PIXELS / 4..FACE_PIXELS * 3 / 4;
    eyes.par_iter()
        .map(|eye| {
            let mut seen = vec![0u64; triangles.len()];
            for forward in [DVec3::X, DVec3::Z, DVec3::NEG_X, DVec3::NEG_Z] {
                let view = View::perspective(eye.eye, -forward, FACE_PIXELS, near);
                let mut depth = vec![f32::INFINITY; FACE_PIXELS * FACE_PIXELS];
                let mut nearest = vec![u32::MAX; FACE_PIXELS * FACE_PIXELS];
                for (t, tri) in triangles.iter().enumerate() {
                    rasterize(&view, tri, |i, d| {
                        if rows.contains(&(i / FACE_PIXELS)) && (d as f32) < depth[i] {
                            depth[i] = d as f32;
                            nearest[i] = t as u32;
                        }
                    });
                }
                for &t in nearest.iter().filter(|&&t| t != u32::MAX) {
                    seen[t as usize] += 1;
                }
            }
            seen
        })
        .reduce(
            || vec![0; triangles.len()],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            },
        )
}

/// The triangles seen most, until `budget` are chosen, no cell taking more than
/// `cell_budget`; triangles never seen are left out. Returns each cell's pieces, each with the
/// triangles chosen of it.
fn choose(
    pieces: &[SurfacePiece],
    cells: &BTreeMap<[i32; 3], Vec<usize>>,
    seen: &[u64],
    budget: usize,
    cell_budget: usize,
) -> Vec<Vec<SurfacePiece>> {
    let mut first = Vec::with_capacity(pieces.len());
    let mut next = 0;
    for piece in pieces {
        first.push(next);
        next += piece.triangles.len();
    }
    // (seen, cell, piece, triangle), most seen first.
    let mut order: Vec<(u64, usize, usize, usize)> = cells
        .values()
        .enumerate()
        .flat_map(|(c, members)| members.iter().map(move |&p| (c, p)))
        .flat_map(|(c, p)| (0..pieces[p].triangles.len()).map(move |t| (c, p, t)))
        .map(|(c, p, t)| (seen[first[p] + t], c, p, t))
        .filter(|&(n, ..)| n > 0)
        .collect();
    order.sort_by(|a, b| b.0.cmp(&a.0).then((a.2, a.3).cmp(&(b.2, b.3))));
    let mut picked: Vec<BTreeMap<usize, Vec<usize>>> = vec![BTreeMap::new(); cells.len()];
    let (mut spent, mut cell_spent) = (0, vec![0; cells.len()]);
    for (_, c, p, t) in order {
        if spent < budget && cell_spent[c] < cell_budget {
            spent += 1;
            cell_spent[c] += 1;
            picked[c].entry(p).or_default().push(t);
        }
    }
    picked
        .into_iter()
        .map(|chosen| {
            chosen
                .into_iter()
                .map(|(p, mut triangles)| {
                    triangles.sort_unstable();
                    let piece = &pieces[p];
                    let triangles: Vec<[[f64; 3]; 3]> = triangles.iter().map(|&t| piece.triangles[t]).collect();
                    let area = triangles
                        .iter()
                        .map(|t| {
                            let [a, b, c] = t.map(DVec3::from_array);
                            0.5 * (b - a).cross(c - a).length()
                        })
                        .sum();
                    SurfacePiece {
                        triangles,
                        area,
                        source_triangles: piece.source_triangles,
                        double_sided: true,
                    }
                })
                .collect()
        })
        .collect()
}

/// What the cache keeps of a soup's bake beside its GLB.
#[derive(Serialize, Deserialize)]
struct SoupRecord {
    soup: SoupInfo,
    batches: Vec<BatchInfo>,
}

/// Bakes `level` as one soup: every instance placed into one map, cooked by [`cook_soup`] (or
/// found in `store` by the map's key), its cells merged into batches. `why` says why it is
/// cooked as a soup, for the report's notes.
pub async fn bake_soup(level: &Level, settings: &Settings, store: &dyn Store, why: &str) -> Result<Baked, LevelError> {
    let started = Instant::now();
    let mut timings = crate::cook::Timings::default();
    let meshes = super::placed_meshes(level, store, &settings.ingest_limits())
        .await
        .map_err(|message| LevelError::BadMesh {
            mesh: level.name.clone(),
            message,
        })?;
    let map = super::cull::placed_map(level, &meshes);
    let key = soup_key(&map, settings);
    timings
        .0
        .push(("read+key".into(), started.elapsed().as_secs_f64() * 1e3));
    let cached = match store.result_glb(&key).await? {
        Some(glb) => store
            .result_report(&key)
            .await?
            .and_then(|json| serde_json::from_slice::<SoupRecord>(&json).ok())
            .map(|record| (glb, record)),
        None => None,
    };
    let cache_hits = usize::from(cached.is_some());
    let (glb, record, stored) = match cached {
        Some((glb, record)) => (glb, record, Vec::new()),
        None => {
            let placement = crate::gpu::for_choice(settings.cook.device).map_err(crate::cook::CookError::from)?;
            let (cells, soup) =
                cook_soup(&map, &settings.level, placement.gpu.as_deref(), &mut timings).map_err(|message| {
                    LevelError::BadMesh {
                        mesh: level.name.clone(),
                        message,
                    }
                })?;
            let (glb, batches) = batch_cells(&cells, &settings.level);
            let record = SoupRecord { soup, batches };
            let json = serde_json::to_vec(&record).expect("records serialize");
            let meta = ResultMeta {
                job: "level-soup".into(),
                bytes: (glb.len() + json.len()) as u64,
                created_ms: now_ms(),
            };
            store.put_result(&key, &glb, &json, &meta).await?;
            (glb, record, vec![(key, meta.bytes)])
        }
    };
    let report = LevelReport {
        name: level.name.clone(),
        instances: level.instances.len(),
        unique_meshes: 1,
        cache_hits,
        batches: record.batches.len(),
        triangles_before: map.triangles.len(),
        triangles_after: record.batches.iter().map(|b| b.triangles).sum(),
        hidden_triangles_removed: 0,
        draw_calls_before: level.instances.len(),
        draw_calls_after: record.batches.len(),
        cull: None,
        soup: Some(record.soup),
        timings_ms: timings,
        notes: vec![
            format!("cooked as one soup: {why}"),
            "the instance cull test does not apply to a soup: run cull-eval --probes".into(),
        ],
    };
    Ok(Baked {
        glb,
        stored,
        batches: record.batches,
        report,
    })
}

/// The key of a soup's bake: the map's, with the level settings that shape it.
fn soup_key(map: &Mesh, settings: &Settings) -> String {
    let mut hasher = blake3::Hasher::new();
    hasher.update(cache_key(map, &settings.cook).as_bytes());
    hasher.update(b"\0soup\0");
    let mut level = serde_json::to_value(&settings.level).expect("settings serialize");
    level
        .as_object_mut()
        .expect("settings are a table")
        .remove("cull_cameras");
    hasher.update(level.to_string().as_bytes());
    hasher.finalize().to_hex().to_string()
}

/// The cells' occluders clustered into batches, one double-sided glTF mesh each.
fn batch_cells(cells: &[CellOccluder], settings: &LevelSettings) -> (Vec<u8>, Vec<BatchInfo>) {
    let placed: Vec<Placed> = cells
        .iter()
        .map(|c| Placed {
            lo: c.lo,
            hi: c.hi,
            triangles: c.mesh.triangles.len(),
        })
        .collect();
    let groups = cluster(&placed, settings.batch_max_triangles, settings.batch_max_extent);
    let meshes: Vec<Mesh> = groups
        .iter()
        .map(|group| {
            let mut mesh = Mesh::default();
            for &c in group {
                mesh.append(&cells[c].mesh);
            }
            mesh
        })
        .collect();
    let mut batches = Vec::with_capacity(groups.len());
    let mut nodes = Vec::with_capacity(groups.len());
    for (b, (group, mesh)) in groups.iter().zip(&meshes).enumerate() {
        let (lo, hi) = point_bounds(group.iter().flat_map(|&c| [placed[c].lo, placed[c].hi]));
        let info = BatchInfo {
            name: format!("batch-{b}"),
            lo: lo.to_array(),
            hi: hi.to_array(),
            triangles: mesh.triangles.len(),
            instances: Vec::new(),
        };
        nodes.push(glb::Node {
            name: info.name.clone(),
            parts: vec![glb::Part {
                name: crate::occluder::PANELS_PART,
                mesh,
                double_sided: true,
            }],
            extras: serde_json::json!({ "bounds": { "min": info.lo, "max": info.hi }, "triangles": info.triangles,
                "cells": group.len() }),
        });
        batches.push(info);
    }
    (glb::write_scene(&nodes), batches)
}

/// Why a level should cook as a soup, if it should: it was read from one file (its instances
/// are its own parts), it is over 50 eye heights long, and either it is one mesh over 500 of
/// its median edges long, or its parts spread across it (the average part's bounds hold over a
/// twentieth of the level's).
pub fn soup_reason(level: &Level, settings: &LevelSettings) -> Option<String> {
    let parts: Vec<(&Mesh, &glam::DMat4)> = level
        .instances
        .iter()
        .map(|(m, matrix)| match m {
            super::MeshRef::Part(p) => Some((&level.parts[*p].1, matrix)),
            _ => None,
        })
        .collect::<Option<_>>()?;
    let boxes: Vec<(DVec3, DVec3)> = parts
        .iter()
        .map(|(mesh, matrix)| point_bounds(mesh.positions.iter().map(|p| matrix.transform_point3(p.as_dvec3()))))
        .collect();
    let (lo, hi) = point_bounds(boxes.iter().flat_map(|&(l, h)| [l, h]));
    let longest = (hi - lo).max_element();
    if longest <= 50.0 * settings.eye_height {
        return None;
    }
    if let [(mesh, _)] = parts[..] {
        let mut edges: Vec<f64> = mesh.triangles_f64().map(|[a, b, _]| (b - a).length()).collect();
        if edges.is_empty() {
            return None;
        }
        let middle = edges.len() / 2;
        let median = *edges.select_nth_unstable_by(middle, f64::total_cmp).1;
        return (longest > 500.0 * median).then(|| {
            format!(
                "one mesh {longest:.0} units long, {:.0} times its median edge",
                longest / median
            )
        });
    }
    // Flat parts (a floor) count with a hundredth of the level's size as their thickness.
    let volume = |(l, h): (DVec3, DVec3)| ((h - l) + longest * 0.01).element_product();
    let share = boxes.iter().map(|&b| volume(b)).sum::<f64>() / boxes.len() as f64 / volume((lo, hi));
    (share > 0.05).then(|| {
        format!(
            "its {} parts spread across it (the average part's bounds hold {:.0}% of the level's)",
            boxes.len(),
            share * 100.0
        )
    })
}
