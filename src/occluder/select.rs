//! Choosing pieces by what they add to the silhouette, not by volume: a box, panel or surface
//! piece enters only when it covers enough pixels of the original's silhouette that nothing
//! chosen covers yet, and the piece that adds the most pixels per triangle of the occluder goes
//! first.

use super::{WorldBox, merge::merge};
use crate::geom::camera::{View, fibonacci_sphere};
use crate::geom::raster::coverage_mask;
use crate::mesh::Mesh;
use rayon::prelude::*;

/// Views and pixels of the selection's silhouettes: coarser than `eval`'s, enough to rank boxes.
const VIEWS: usize = 24;
const PIXELS: usize = 128;
/// Candidates, by silhouette gain, whose real triangle cost is measured at each step.
const LOOKAHEAD: usize = 8;
/// Rounds of filling the budget and dropping what became redundant.
const PRUNE_ROUNDS: usize = 4;

pub struct Selection {
    /// Indices into the candidate boxes, in the order chosen.
    pub boxes: Vec<usize>,
    /// Indices into the candidate sheets, in the order chosen.
    pub sheets: Vec<usize>,
    /// Silhouette share each chosen piece added, in the order chosen.
    pub gains: Vec<f64>,
    /// Silhouette share the chosen pieces cover together.
    pub covered: f64,
    /// Triangles of the merged solid and the chosen sheets.
    pub triangles: usize,
    /// The merged union of the chosen boxes. With the chosen sheets' triangles, it stays within
    /// the triangle budget.
    pub solid: Mesh,
}

/// Candidates are the boxes, then the sheets (double-sided pieces: panels and surface pieces,
/// each costing its triangles): index `i` is a box below `boxes.len()`.
pub fn select(mesh: &Mesh, boxes: &[WorldBox], sheets: &[Mesh], max_triangles: usize, min_gain: f64) -> Selection {
    if boxes.is_empty() && sheets.is_empty() {
        return Selection {
            boxes: Vec::new(),
            sheets: Vec::new(),
            gains: Vec::new(),
            covered: 0.0,
            triangles: 0,
            solid: Mesh::default(),
        };
    }
    let (center, radius) = mesh.bounding_sphere();
    let views: Vec<View> = fibonacci_sphere(VIEWS)
        .into_iter()
        .map(|d| View::new(d, center, radius, PIXELS))
        .collect();
    let silhouettes: Vec<Vec<u64>> = views.par_iter().map(|v| coverage_mask(v, mesh)).collect();
    let total: u64 = silhouettes.iter().flatten().map(|w| u64::from(w.count_ones())).sum();
    let box_shapes: Vec<Mesh> = boxes.iter().map(|b| merge(std::slice::from_ref(b))).collect();
    let shapes: Vec<&Mesh> = box_shapes.iter().chain(sheets).collect();
    let costs: Vec<usize> = shapes.iter().map(|s| s.triangles.len()).collect();
    let words: usize = silhouettes.iter().map(Vec::len).sum();
    // masks[candidate]: the silhouette pixels it covers, one bit each, all views end to end,
    // as its nonzero words: a piece covers a small part of the silhouette.
    let masks: Vec<SparseMask> = shapes
        .par_iter()
        .map(|shape| {
            let mut offset = 0;
            let mut mask = Vec::new();
            for (v, s) in views.iter().zip(&silhouettes) {
                let m = coverage_mask(v, shape);
                for (w, (a, b)) in m.into_iter().zip(s).enumerate() {
                    if a & b != 0 {
                        mask.push(((offset + w) as u32, a & b));
                    }
                }
                offset += s.len();
            }
            mask
        })
        .collect();
    let mut state = State {
        boxes,
        masks: &masks,
        costs: &costs,
        words,
        threshold: (min_gain * total as f64).max(1.0),
        max_triangles,
        chosen: Vec::new(),
        solid: Mesh::default(),
    };
    for round in 1.. {
        state.fill();
        if round == PRUNE_ROUNDS || !state.prune() {
            break;
        }
    }
    let total = total.max(1) as f64;
    let covered = state.covered().iter().map(|w| f64::from(w.count_ones())).sum::<f64>() / total;
    Selection {
        covered,
        triangles: state.triangles(),
        boxes: state.chosen.iter().filter(|c| c.0 < boxes.len()).map(|c| c.0).collect(),
        sheets: state
            .chosen
            .iter()
            .filter(|c| c.0 >= boxes.len())
            .map(|c| c.0 - boxes.len())
            .collect(),
        gains: state.chosen.iter().map(|c| c.1 as f64 / total).collect(),
        solid: state.solid,
    }
}

/// The nonzero words of a bitmask: (word index, bits).
type SparseMask = Vec<(u32, u64)>;

/// The greedy selection as it goes: candidates are the boxes, then the sheets.
struct State<'a> {
    boxes: &'a [WorldBox],
    masks: &'a [SparseMask],
    /// Triangles of each candidate alone.
    costs: &'a [usize],
    /// Words of a dense mask.
    words: usize,
    /// Fewest new silhouette pixels that earn a piece its place.
    threshold: f64,
    max_triangles: usize,
    /// (candidate, pixels it added), in the order chosen.
    chosen: Vec<(usize, u64)>,
    /// The merged union of the chosen boxes.
    solid: Mesh,
}

impl State<'_> {
    fn triangles(&self) -> usize {
        self.solid.triangles.len()
            + self
                .chosen
                .iter()
                .filter(|c| c.0 >= self.boxes.len())
                .map(|c| self.costs[c.0])
                .sum::<usize>()
    }

    fn merged_with(&self, extra: Option<usize>) -> Mesh {
        let boxes: Vec<WorldBox> = self
            .chosen
            .iter()
            .map(|c| c.0)
            .chain(extra)
            .filter(|&i| i < self.boxes.len())
            .map(|i| self.boxes[i])
            .collect();
        merge(&boxes)
    }

    fn covered(&self) -> Vec<u64> {
        let mut covered = vec![0u64; self.words];
        for &(i, _) in &self.chosen {
            for &(w, bits) in &self.masks[i] {
                covered[w as usize] |= bits;
            }
        }
        covered
    }

    /// Adds the piece with the most new pixels per triangle until the budget is spent.
    fn fill(&mut self) {
        let mut covered = self.covered();
        loop {
            let gain = |i: usize| -> u64 {
                self.masks[i]
                    .iter()
                    .map(|&(w, bits)| u64::from((bits & !covered[w as usize]).count_ones()))
                    .sum()
            };
            let mut ranked: Vec<(usize, u64)> = (0..self.masks.len())
                .filter(|&i| self.chosen.iter().all(|c| c.0 != i))
                .map(|i| (i, gain(i)))
                .filter(|&(_, g)| g as f64 >= self.threshold)
                .collect();
            ranked.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            let used = self.triangles();
            // A sheet costs its triangles. The merge decides what a box really costs: touching
            // boxes share faces, and T-junctions add vertices; price the best few by merging
            // them in.
            let priced_sheets = ranked
                .iter()
                .filter(|&&(i, _)| i >= self.boxes.len())
                .filter(|&&(i, _)| used + self.costs[i] <= self.max_triangles)
                .map(|&(i, g)| (i, g, g as f64 / self.costs[i].max(1) as f64, None));
            let priced_boxes = ranked
                .iter()
                .filter(|&&(i, _)| i < self.boxes.len())
                .take(LOOKAHEAD)
                .filter_map(|&(i, g)| {
                    let solid = self.merged_with(Some(i));
                    let added = solid.triangles.len().saturating_sub(self.solid.triangles.len());
                    (used + added <= self.max_triangles).then(|| (i, g, g as f64 / added.max(1) as f64, Some(solid)))
                });
            let best = priced_sheets
                .chain(priced_boxes)
                .max_by(|a, b| a.2.total_cmp(&b.2).then(b.0.cmp(&a.0)));
            let Some((i, pixels, _, solid)) = best else {
                break;
            };
            for &(w, bits) in &self.masks[i] {
                covered[w as usize] |= bits;
            }
            self.chosen.push((i, pixels));
            if let Some(solid) = solid {
                self.solid = solid;
            }
        }
    }

    /// Drops pieces that later ones made redundant (no pixel of their own), so that a later
    /// fill can spend their triangles. Whether any went.
    fn prune(&mut self) -> bool {
        let mut counts = vec![0u16; self.words * 64];
        let set_bits = |mask: &SparseMask| {
            mask.iter()
                .flat_map(|&(w, word)| {
                    (0..64)
                        .filter(move |b| word >> b & 1 == 1)
                        .map(move |b| w as usize * 64 + b)
                })
                .collect::<Vec<usize>>()
        };
        let pixels: Vec<Vec<usize>> = self.chosen.iter().map(|c| set_bits(&self.masks[c.0])).collect();
        for p in pixels.iter().flatten() {
            counts[*p] += 1;
        }
        let mut keep = vec![true; self.chosen.len()];
        loop {
            let own = |k: usize| pixels[k].iter().filter(|&&p| counts[p] == 1).count();
            let Some(k) = (0..self.chosen.len()).find(|&k| keep[k] && own(k) == 0) else {
                break;
            };
            keep[k] = false;
            for p in &pixels[k] {
                counts[*p] -= 1;
            }
        }
        if keep.iter().all(|&k| k) {
            return false;
        }
        let mut k = 0;
        self.chosen.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        self.solid = self.merged_with(None);
        true
    }
}
