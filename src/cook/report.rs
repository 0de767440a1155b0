//! What a cook returns: the occluder, its GLB, and the report of every stage.

use crate::eval::Quality;
use crate::mesh::{IngestStats, Topology, glb};
use crate::occluder::{Occluder, Panel, Shape, WorldBox, boxes::VoxelBox};
use crate::voxel::{Classified, Grid, cpsv::CpsvStats};
use serde::Serialize;

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

impl Timings {
    /// A stage that runs in several places adds up under one name.
    pub(crate) fn add(&mut self, stage: &str, ms: f64) {
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
    /// Openings narrower than `cook.smallest_hole`, counted as closed.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub openings_closed: Vec<crate::geom::openings::Opening>,
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
    /// Wall-clock milliseconds of the cook, ingest included and eval left out. Some stages run
    /// side by side, so this can be less than their times' sum.
    pub cook_ms: f64,
    /// The device's own milliseconds per stage: its passes, from timestamp queries. Empty on
    /// the CPU and on adapters without timestamps.
    #[serde(skip_serializing_if = "Timings::is_empty")]
    pub device_timings_ms: Timings,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quality: Option<Quality>,
    /// Why the occluder is empty or smaller than asked, in words.
    pub notes: Vec<String>,
}

impl Report {
    /// Wall-clock milliseconds of the cook and its eval.
    pub fn total_ms(&self) -> f64 {
        self.cook_ms + self.timings_ms.get("eval")
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct InputReport {
    #[serde(flatten)]
    pub ingest: IngestStats,
    pub triangles: usize,
    #[serde(flatten)]
    pub topology: Topology,
}

impl InputReport {
    /// The mesh as read (`triangles` of it): before any opening is closed.
    pub fn new(triangles: usize, ingest: IngestStats, topology: &Topology) -> InputReport {
        InputReport {
            ingest,
            triangles,
            topology: topology.clone(),
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct VoxelReport {
    pub surface: usize,
    pub solid: usize,
    pub inner: usize,
    /// Inner voxels left out because they show through an opening (open meshes only).
    pub exposed: usize,
    /// Cells, seeds and undecided cells of `inside = "cpsv"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpsv: Option<CpsvStats>,
}

impl VoxelReport {
    pub(super) fn new(surface: &[bool], inside: &Classified, inner: usize, exposed: usize) -> VoxelReport {
        VoxelReport {
            surface: surface.iter().filter(|&&v| v).count(),
            solid: inside.solid.iter().filter(|&&v| v).count(),
            inner,
            exposed,
            cpsv: inside.cpsv.clone(),
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct BoxReport {
    pub candidates: usize,
    /// Candidates rejected because they show through an opening (open meshes only).
    pub exposed: usize,
    pub kept: usize,
    /// Share of the inner voxels that the kept boxes fill.
    pub inner_volume_covered: f64,
    pub kept_boxes: Vec<WorldBox>,
}

impl BoxReport {
    /// `voxel_boxes` as expanded, `candidates` those that do not show through an opening (the
    /// one at `sources[i]` of `voxel_boxes` refined into `candidates[i]`), and `kept` the indices
    /// of the chosen candidates; `inner` counts the inner voxels, `exposed` the boxes an opening
    /// showed.
    pub(super) fn new(
        voxel_boxes: &[VoxelBox],
        candidates: &[WorldBox],
        sources: &[usize],
        kept: &[usize],
        [inner, exposed]: [usize; 2],
    ) -> BoxReport {
        let kept_voxels: usize = kept.iter().map(|&i| voxel_boxes[sources[i]].voxels()).sum();
        BoxReport {
            candidates: voxel_boxes.len(),
            exposed,
            kept: kept.len(),
            inner_volume_covered: if inner > 0 {
                kept_voxels as f64 / inner as f64
            } else {
                0.0
            },
            kept_boxes: kept.iter().map(|&i| candidates[i]).collect(),
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct PanelReport {
    /// In-solid quads found, before selection.
    pub quad_candidates: usize,
    /// On-surface patches found, before selection.
    pub patch_candidates: usize,
    /// Quads rejected because they show through an opening (open meshes only).
    pub exposed: usize,
    /// Quads that showed in part, cut down to their largest hidden rectangle.
    pub cut: usize,
    pub kept_panels: Vec<Panel>,
    /// Flat regions of the surface the selection weighed.
    pub surface_piece_candidates: usize,
}

impl PanelReport {
    /// `found` quads, of which `dropped` showed through an opening and `cut` showed in part,
    /// then patches up to `candidates` panels in all, and `pieces` surface pieces weighed.
    pub(super) fn new(
        found: usize,
        [dropped, cut]: [usize; 2],
        candidates: usize,
        pieces: usize,
        occluder: &Occluder,
    ) -> PanelReport {
        PanelReport {
            quad_candidates: found,
            patch_candidates: candidates - (found - dropped),
            exposed: dropped,
            cut,
            kept_panels: occluder.panels.clone(),
            surface_piece_candidates: pieces,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct OccluderReport {
    pub triangles: usize,
    pub vertices: usize,
    pub boxes: usize,
    pub quads: usize,
    pub patches: usize,
    /// Flat regions of the surface, drawn double-sided.
    pub surface_pieces: usize,
    /// Silhouette share each piece added when it was chosen, in the order chosen.
    pub silhouette_gains: Vec<f64>,
}

impl OccluderReport {
    pub(super) fn new(occluder: &Occluder, boxes: usize, silhouette_gains: Vec<f64>) -> OccluderReport {
        OccluderReport {
            triangles: occluder.triangles(),
            vertices: occluder.vertices(),
            boxes,
            quads: occluder.panels.iter().filter(|p| p.shape == Shape::Quads).count(),
            patches: occluder.panels.iter().filter(|p| p.shape == Shape::Patches).count(),
            surface_pieces: occluder.pieces.len(),
            silhouette_gains,
        }
    }
}

pub struct Cooked {
    pub occluder: Occluder,
    pub report: Report,
}

impl Cooked {
    /// The occluder as a GLB: the watertight solid and the double-sided panels and pieces as two
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
            "surface_pieces": r.occluder.surface_pieces,
            "triangles": r.occluder.triangles,
        });
        let solid = self.occluder.single_sided();
        let panels = self.occluder.double_sided();
        let parts = [
            glb::Part {
                name: crate::occluder::SOLID_PART,
                mesh: &solid,
                double_sided: false,
            },
            glb::Part {
                name: crate::occluder::PANELS_PART,
                mesh: &panels,
                double_sided: true,
            },
        ];
        glb::write(&parts, extras)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_inner_volume_covered_counts_the_voxels_of_the_boxes_kept() {
        // Three voxel boxes of 8, 27 and 1 voxels; the second showed through an opening, so
        // the candidates are the first and the third, and the selection keeps the third.
        let voxel_boxes = [([0, 0, 0], [2, 2, 2]), ([2, 0, 0], [5, 3, 3]), ([5, 0, 0], [6, 1, 1])]
            .map(|(lo, hi)| VoxelBox { lo, hi });
        let candidates = [WorldBox {
            lo: [0.0; 3],
            hi: [1.0; 3],
        }; 2];
        let report = BoxReport::new(&voxel_boxes, &candidates, &[0, 2], &[1], [40, 1]);
        assert_eq!((report.candidates, report.exposed, report.kept), (3, 1, 1));
        assert_eq!(report.inner_volume_covered, 1.0 / 40.0);
    }
}
