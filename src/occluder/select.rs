//! Choosing pieces by what they add to the silhouette, not by volume: a box, panel or surface
//! piece enters only when it covers enough pixels of the original's silhouette that nothing
//! chosen covers yet, and the piece that adds the most pixels per triangle of the occluder goes
//! first.

use super::WorldBox;
use super::merge::{merge, merged_triangles};
use crate::geom::camera::{View, fibonacci_sphere};
use crate::geom::raster::{DrawBuffers, coverage_mask, draw_coverage};
use crate::geom::with_popcnt;
use crate::mesh::Mesh;
use rayon::prelude::*;
use std::cmp::{Ordering, Reverse};
use std::collections::{BinaryHeap, HashMap};

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

/// The original's silhouettes in the selection's views: they depend on the mesh alone, so a
/// cook finds them while other stages run, and once for both selections it may make.
pub struct Silhouettes {
    views: Vec<View>,
    /// Each view's covered pixels, a bit each.
    masks: Vec<Vec<u64>>,
    /// Their pixels in all.
    pixels: u64,
}

impl Silhouettes {
    /// `open_triangles` marks the triangles of parts of the surface with an open boundary.
    pub fn new(mesh: &Mesh, open_triangles: &[bool]) -> Silhouettes {
        let (center, radius) = mesh.bounding_sphere();
        let views: Vec<View> = fibonacci_sphere(VIEWS)
            .into_iter()
            .map(|d| View::new(d, center, radius, PIXELS))
            .collect();
        let open = open_triangles.contains(&false).then_some(open_triangles);
        let masks: Vec<Vec<u64>> = views.par_iter().map(|v| coverage_mask(v, mesh, open)).collect();
        let pixels = masks.iter().flatten().map(|w| u64::from(w.count_ones())).sum();
        Silhouettes { views, masks, pixels }
    }
}

/// Candidates are the boxes, then the sheets (double-sided pieces: panels and surface pieces,
/// each costing its triangles): index `i` is a box below `boxes.len()`. A piece enters when it
/// adds `min_gain` of the silhouette, and stays if it still has `min_own` of its own at the end.
pub fn select(
    silhouettes: &Silhouettes,
    boxes: &[WorldBox],
    sheets: &[Mesh],
    max_triangles: usize,
    (min_gain, min_own): (f64, f64),
) -> Selection {
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
    let (views, total, silhouettes) = (&silhouettes.views, silhouettes.pixels, &silhouettes.masks);
    let box_shapes: Vec<Mesh> = boxes.iter().map(|b| merge(std::slice::from_ref(b))).collect();
    let shapes: Vec<&Mesh> = box_shapes.iter().chain(sheets).collect();
    let costs: Vec<usize> = shapes.iter().map(|s| s.triangles.len()).collect();
    let words: usize = silhouettes.iter().map(Vec::len).sum();
    // masks[candidate]: the silhouette pixels it covers, one bit each, all views end to end,
    // as its nonzero words: a piece covers a small part of the silhouette.
    // One view's bits at a time, cleared after over the words drawn; with what drawing works
    // out for each vertex, kept from shape to shape.
    let room = || {
        (
            vec![0u64; silhouettes.first().map_or(0, Vec::len)],
            DrawBuffers::default(),
        )
    };
    let masks: Vec<SparseMask> = shapes
        .par_iter()
        .map_init(room, |(image, buffers), shape| {
            let mut offset = 0;
            let mut mask = Vec::new();
            for (v, s) in views.iter().zip(silhouettes) {
                for w in draw_coverage(v, shape, image, buffers) {
                    if image[w] & s[w] != 0 {
                        mask.push(((offset + w) as u32, image[w] & s[w]));
                    }
                    image[w] = 0;
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
    state.choose((min_own * total as f64).ceil() as u64);
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

/// New pixels per triangle.
fn ratio(pixels: u64, triangles: usize) -> f64 {
    pixels as f64 / triangles.max(1) as f64
}

/// A candidate's new pixels per triangle (in the lazy greedy queue, an upper bound on them).
/// The larger ratio, then the lower index, ranks higher.
#[derive(Clone, Copy)]
struct Rank {
    ratio: f64,
    candidate: usize,
}

impl Ord for Rank {
    fn cmp(&self, other: &Rank) -> Ordering {
        self.ratio
            .total_cmp(&other.ratio)
            .then(other.candidate.cmp(&self.candidate))
    }
}

impl PartialOrd for Rank {
    fn partial_cmp(&self, other: &Rank) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Rank {
    fn eq(&self, other: &Rank) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Rank {}

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

    /// The chosen boxes, and box `extra` if given.
    fn boxes_with(&self, extra: Option<usize>) -> Vec<WorldBox> {
        self.chosen
            .iter()
            .map(|c| c.0)
            .chain(extra)
            .filter(|&i| i < self.boxes.len())
            .map(|i| self.boxes[i])
            .collect()
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
    ///
    /// A piece's gain only shrinks as pixels are covered, so each sheet keeps its last gain as
    /// a bound, and sheets are weighed again in order of that bound per triangle only until the
    /// best weighed one leads every bound: lazy greedy, the same picks as weighing all.
    fn fill(&mut self) {
        let mut covered = self.covered();
        let mut taken = vec![false; self.masks.len()];
        for c in &self.chosen {
            taken[c.0] = true;
        }
        let first_sheet = self.boxes.len();
        // Untaken sheets by their bound per triangle, best first: a sheet's key is its bound.
        let mut queue: BinaryHeap<Rank> = (first_sheet..self.masks.len())
            .filter(|&i| !taken[i])
            .map(|i| Rank {
                ratio: ratio(self.gain(&covered, i), self.costs[i]),
                candidate: i,
            })
            .collect();
        // Untaken boxes by their bound: their gain when last weighed.
        let mut box_queue: BinaryHeap<(u64, Reverse<usize>)> = (0..first_sheet)
            .filter(|&i| !taken[i])
            .map(|i| (self.gain(&covered, i), Reverse(i)))
            .collect();
        // The triangles of the chosen boxes' solid with each box merged in.
        let mut with_box: HashMap<usize, usize> = HashMap::new();
        loop {
            let used = self.triangles();
            let best_sheet = self.best_sheet(&mut queue, &taken, &covered, used);
            // The merge decides what a box really costs: touching boxes share faces, and
            // T-junctions add vertices; price the best few by counting the triangles of the
            // merge with each (the chosen one's is made). A price holds until the chosen boxes
            // change.
            let lookahead = self.best_boxes(&mut box_queue, &taken, &covered);
            let unpriced: Vec<usize> = lookahead
                .iter()
                .map(|&(i, _)| i)
                .filter(|i| !with_box.contains_key(i))
                .collect();
            let merged: Vec<(usize, usize)> = unpriced
                .into_par_iter()
                .map(|i| (i, merged_triangles(&self.boxes_with(Some(i)))))
                .collect();
            with_box.extend(merged);
            let priced_boxes = lookahead.iter().filter_map(|&(i, g)| {
                let added = with_box[&i].saturating_sub(self.solid.triangles.len());
                let rank = Rank {
                    ratio: ratio(g, added),
                    candidate: i,
                };
                (used + added <= self.max_triangles).then_some((rank, g))
            });
            let best = best_sheet.into_iter().chain(priced_boxes).max_by_key(|&(rank, _)| rank);
            let Some((Rank { candidate: i, .. }, pixels)) = best else {
                break;
            };
            for &(w, bits) in &self.masks[i] {
                covered[w as usize] |= bits;
            }
            self.chosen.push((i, pixels));
            taken[i] = true;
            if i < first_sheet {
                self.solid = merge(&self.boxes_with(None));
                with_box.clear();
            }
        }
    }

    /// The untaken boxes with the most new pixels, ties to the lower index, best first: at most
    /// `LOOKAHEAD`, each adding enough. As with sheets, boxes are weighed in order of their
    /// bound in `queue` only until `LOOKAHEAD` weighed ones lead every bound left; a box that
    /// adds too few never adds enough again in this fill, and leaves the queue.
    fn best_boxes(
        &self,
        queue: &mut BinaryHeap<(u64, Reverse<usize>)>,
        taken: &[bool],
        covered: &[u64],
    ) -> Vec<(usize, u64)> {
        // Weighed boxes as (gain, index) keys, best first.
        let mut weighed: Vec<(u64, Reverse<usize>)> = Vec::new();
        while let Some(&bound) = queue.peek() {
            if weighed.get(LOOKAHEAD - 1).is_some_and(|&last| bound < last) {
                break;
            }
            queue.pop();
            let i = bound.1.0;
            if taken[i] {
                continue;
            }
            let key = (self.gain(covered, i), Reverse(i));
            if key.0 as f64 >= self.threshold {
                let at = weighed.partition_point(|&k| k > key);
                weighed.insert(at, key);
            }
        }
        queue.extend(weighed.iter().copied());
        weighed.truncate(LOOKAHEAD);
        weighed.into_iter().map(|(gain, Reverse(i))| (i, gain)).collect()
    }

    /// Silhouette pixels that candidate `i` covers and `covered` does not: most of the greedy
    /// fill's time.
    fn gain(&self, covered: &[u64], i: usize) -> u64 {
        with_popcnt(|| {
            self.masks[i]
                .iter()
                .map(|&(w, bits)| u64::from((bits & !covered[w as usize]).count_ones()))
                .sum()
        })
    }

    /// The untaken sheet within the budget with the most new pixels per triangle, if it adds
    /// enough, with its rank and new pixels: sheets are weighed in order of their bound in
    /// `queue` until the best weighed leads the next bound; their new gains become their bounds.
    fn best_sheet(
        &self,
        queue: &mut BinaryHeap<Rank>,
        taken: &[bool],
        covered: &[u64],
        used: usize,
    ) -> Option<(Rank, u64)> {
        let mut best: Option<(Rank, u64)> = None;
        // Sheets weighed or over the budget, to go back in the queue after.
        let mut aside = Vec::new();
        while let Some(&top) = queue.peek() {
            let i = top.candidate;
            if taken[i] {
                queue.pop();
                continue;
            }
            if used + self.costs[i] > self.max_triangles {
                aside.push(queue.pop().expect("peeked"));
                continue;
            }
            if best.is_some_and(|(b, _)| b > top) {
                break;
            }
            queue.pop();
            let g = self.gain(covered, i);
            let weighed = Rank {
                ratio: ratio(g, self.costs[i]),
                candidate: i,
            };
            aside.push(weighed);
            if g as f64 >= self.threshold && best.is_none_or(|(b, _)| weighed > b) {
                best = Some((weighed, g));
            }
        }
        queue.extend(aside);
        best
    }

    /// Drops pieces that later ones left with fewer than `least` pixels of their own, the
    /// fewest first (the earliest chosen of those as few), each drop giving the others back the
    /// pixels they shared with it. Whether any went.
    fn prune(&mut self, least: u64) -> bool {
        let mut keep = vec![true; self.chosen.len()];
        let (mut once, mut more) = (vec![0u64; self.words], vec![0u64; self.words]);
        loop {
            // The pixels the kept pieces cover once, and those they cover more than once.
            once.fill(0);
            more.fill(0);
            for (c, _) in self.chosen.iter().zip(&keep).filter(|(_, kept)| **kept) {
                for &(w, word) in &self.masks[c.0] {
                    let w = w as usize;
                    more[w] |= once[w] & word;
                    once[w] = (once[w] ^ word) & !more[w];
                }
            }
            let own = |k: usize| -> u64 {
                self.masks[self.chosen[k].0]
                    .iter()
                    .map(|&(w, word)| u64::from((word & once[w as usize]).count_ones()))
                    .sum()
            };
            let fewest = (0..self.chosen.len()).filter(|&k| keep[k]).map(|k| (own(k), k)).min();
            match fewest {
                Some((pixels, k)) if pixels < least => keep[k] = false,
                _ => break,
            }
        }
        if keep.iter().all(|&k| k) {
            return false;
        }
        // The solid changes only where a box went.
        let first_sheet = self.boxes.len();
        let box_dropped = self
            .chosen
            .iter()
            .zip(&keep)
            .any(|(c, &kept)| !kept && c.0 < first_sheet);
        let mut k = 0;
        self.chosen.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        if box_dropped {
            self.solid = merge(&self.boxes_with(None));
        }
        true
    }

    /// Fills the budget, drops what later pieces made redundant and fills again, a few rounds;
    /// then drops, with nothing to take their place, the pieces left with fewer than `least_own`
    /// pixels of their own: what they add no longer pays for their triangles.
    fn choose(&mut self, least_own: u64) {
        for round in 1.. {
            self.fill();
            if round == PRUNE_ROUNDS || !self.prune(1) {
                break;
            }
        }
        self.prune(least_own);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `count` masks over `words` words, each a run of fewer than `longest` words from a random
    /// first, their bits from `bits`.
    fn random_masks(
        rng: &mut fastrand::Rng,
        [count, words, longest]: [usize; 3],
        bits: impl Fn(&mut fastrand::Rng) -> u64,
    ) -> Vec<SparseMask> {
        (0..count)
            .map(|_| {
                let first = rng.usize(0..words);
                let run = first..words.min(first + rng.usize(1..longest));
                run.map(|w| (w as u32, bits(rng))).collect()
            })
            .collect()
    }

    /// A selection state over sheets alone, costing `costs`, with `masks` all chosen in order.
    fn sheets_chosen<'a>(masks: &'a [SparseMask], costs: &'a [usize], words: usize) -> State<'a> {
        State {
            boxes: &[],
            masks,
            costs,
            words,
            threshold: 1.0,
            max_triangles: 256,
            chosen: masks.iter().enumerate().map(|(i, _)| (i, 0)).collect(),
            solid: Mesh::default(),
        }
    }

    #[test]
    fn pruning_drops_the_piece_with_fewest_pixels_of_its_own_first_and_counts_again() {
        // A: words 0-1; B: word 2 and ten bits of word 3; C: words 1-2. A has word 0 alone, B
        // ten bits, C none. Dropping C first gives B word 2 back; the first chosen under 20,
        // B, would have gone instead, and C kept.
        let masks: Vec<SparseMask> = vec![
            vec![(0, u64::MAX), (1, u64::MAX)],
            vec![(2, u64::MAX), (3, 0x3ff)],
            vec![(1, u64::MAX), (2, u64::MAX)],
        ];
        let costs = [2; 3];
        let mut state = sheets_chosen(&masks, &costs, 4);
        assert!(state.prune(20));
        assert_eq!(state.chosen.iter().map(|c| c.0).collect::<Vec<_>>(), [0, 1]);
        // Each has at least 20 of its own now: nothing more goes.
        assert!(!state.prune(20));
        // Under 75, B goes (74 of its own); then A, alone, has all 128 of its pixels.
        assert!(state.prune(75));
        assert_eq!(state.chosen.iter().map(|c| c.0).collect::<Vec<_>>(), [0]);
    }

    #[test]
    fn every_piece_chosen_keeps_the_least_of_its_own_and_the_budget_holds() {
        let mut rng = fastrand::Rng::with_seed(5);
        let words = 32;
        let mut dropped = 0;
        for _ in 0..60 {
            let count = rng.usize(10..60);
            let masks = random_masks(&mut rng, [count, words, 10], |rng| rng.u64(..) & rng.u64(..));
            let costs: Vec<usize> = (0..count).map(|_| rng.usize(1..5) * 2).collect();
            let least = rng.u64(10..80);
            let mut state = sheets_chosen(&masks, &costs, words);
            state.chosen.clear();
            state.max_triangles = rng.usize(10..80);
            state.threshold = rng.usize(1..20) as f64;
            state.fill();
            let filled = state.chosen.len();
            state.prune(least);
            dropped += filled - state.chosen.len();
            assert!(state.triangles() <= state.max_triangles);
            for (k, c) in state.chosen.iter().enumerate() {
                let others: Vec<u64> = (0..words)
                    .map(|w| {
                        let at = |i: usize| masks[i].iter().filter(|m| m.0 as usize == w).fold(0, |a, m| a | m.1);
                        let chosen = state.chosen.iter().enumerate().filter(|&(j, _)| j != k);
                        chosen.fold(0, |a, (_, o)| a | at(o.0))
                    })
                    .collect();
                let own: u64 = masks[c.0]
                    .iter()
                    .map(|&(w, bits)| u64::from((bits & !others[w as usize]).count_ones()))
                    .sum();
                assert!(own >= least, "a piece kept with {own} of its own, under {least}");
            }
        }
        assert!(dropped > 100, "{dropped} pieces dropped");
    }

    #[test]
    fn the_boxes_weighed_lazily_are_those_that_weighing_all_ranks_first() {
        let mut rng = fastrand::Rng::with_seed(11);
        let (words, mut steps) = (40, 0);
        for _ in 0..50 {
            let count = rng.usize(1..60);
            // Overlapping masks, many with equal gains, so that ties to the lower index count.
            let masks = random_masks(&mut rng, [count, words, 12], |rng| {
                [u64::MAX, 0xff, rng.u64(..)][rng.usize(0..3)]
            });
            let boxes = vec![
                WorldBox {
                    lo: [0.0; 3],
                    hi: [1.0; 3]
                };
                count
            ];
            let costs = vec![12; count];
            let state = State {
                boxes: &boxes,
                masks: &masks,
                costs: &costs,
                words,
                threshold: rng.usize(1..40) as f64,
                max_triangles: 256,
                chosen: Vec::new(),
                solid: Mesh::default(),
            };
            let mut covered = vec![0u64; words];
            let mut taken = vec![false; count];
            let mut queue: BinaryHeap<(u64, Reverse<usize>)> =
                (0..count).map(|i| (state.gain(&covered, i), Reverse(i))).collect();
            loop {
                let lazy = state.best_boxes(&mut queue, &taken, &covered);
                let mut all: Vec<(usize, u64)> = (0..count)
                    .filter(|&i| !taken[i])
                    .map(|i| (i, state.gain(&covered, i)))
                    .filter(|&(_, g)| g as f64 >= state.threshold)
                    .collect();
                all.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
                all.truncate(LOOKAHEAD);
                assert_eq!(lazy, all);
                // Take one of them, as the selection might, and cover its pixels.
                let Some(&(i, _)) = lazy.get(rng.usize(0..lazy.len().max(1))) else {
                    break;
                };
                taken[i] = true;
                steps += 1;
                for &(w, bits) in &masks[i] {
                    covered[w as usize] |= bits;
                }
            }
        }
        assert!(steps > 300, "{steps} boxes taken");
    }
}
