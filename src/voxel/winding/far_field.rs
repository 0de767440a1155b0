//! The curtain term far from its edges, with a bound on its error.
//!
//! Each connected run of boundary edges is a closed loop (the boundary of the surface has no
//! ends). Close a loop's curtain with a fan from the loop's centre: the fan, the curtain and the
//! curtain's bottom at infinity bound a region, and a point outside the loop's footprint (its
//! bounding box in x and y) lies outside it, as its upward ray meets neither fan nor curtain.
//! There the curtain's solid angle, as the curtain term sums it, is the fan's (the triangles
//! from the centre to each edge's ends, in the edge's direction), and seen from afar the fan's
//! is that of a dipole: its vector area at the centre. Over a fan of area S within R of the centre, a
//! point r away sees the dipole's solid angle off by at most 2·S·R / (r − R)³, as the kernel
//! (x − p) / |x − p|³ moves by at most 2 / (r − R)³ per unit of x. Loops near one another share
//! one dipole in a tree.

use crate::mesh::point_bounds;
use crate::mesh::topology::linked_components;
use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// A node of the tree over the loops: what its loops' fans sum to, seen from afar.
struct Node {
    centre: DVec3,
    /// Σ of the fans' vector areas: normal times area.
    moment: DVec3,
    /// Σ of the fans' areas.
    area: f64,
    /// How far any point of the fans lies from the centre, at most.
    radius: f64,
    /// The loops' vertices' bounds in x and y.
    lo: DVec2,
    hi: DVec2,
    /// Whether every loop under it closes, so that the dipole stands for it.
    closed: bool,
    children: Children,
}

enum Children {
    /// One loop: its vertices and edges in [`FarField`]'s lists.
    Loop {
        vertices: std::ops::Range<usize>,
        edges: std::ops::Range<usize>,
    },
    Split(usize, usize),
}

/// The curtain's loops in a tree, each node with its dipole.
pub(super) struct FarField {
    nodes: Vec<Node>,
    /// The loops' vertices and edges, loop by loop; the edges' ends index the vertices.
    vertices: Vec<DVec3>,
    edges: Vec<(usize, usize, i32)>,
}

/// The curtain for points in a box: the loops near it, as a curtain of their own (edges whose
/// ends index `near_vertices`), and the tree nodes far from every point of it.
pub(super) struct Split {
    pub near_vertices: Vec<DVec3>,
    pub near_edges: Vec<(usize, usize, i32)>,
    far: Vec<usize>,
}

/// A point lies far from a node when it is more than this many of the node's radii from its
/// centre. The bound falls as the cube of the distance: on 2cylinder-engine's 64³ grid, at 5
/// radii it left 99% of the columns to exact terms, at 7 a fifth, at 8 none.
const FAR: f64 = 8.0;

impl FarField {
    /// The loops of the curtain's `edges` (ends indexing `vertices`, with weights).
    pub(super) fn new(vertices: &[DVec3], edges: &[(usize, usize, i32)]) -> FarField {
        // The loops: the connected runs of edges.
        let ends = edges.iter().map(|&(a, b, _)| (a as u32, b as u32));
        let component = linked_components(vertices.len(), ends);
        let mut by_loop: Vec<(u32, usize)> = (0..edges.len()).map(|e| (component[edges[e].0], e)).collect();
        by_loop.sort_unstable();
        // Each loop's vertices, in the order its edges first reach them.
        let mut slot = vec![usize::MAX; vertices.len()];
        let (mut own_vertices, mut own_edges, mut leaves) = (Vec::new(), Vec::new(), Vec::new());
        for run in by_loop.chunk_by(|a, b| a.0 == b.0) {
            let (first_vertex, first_edge) = (own_vertices.len(), own_edges.len());
            for &(_, e) in run {
                let (a, b, weight) = edges[e];
                let [a, b] = [a, b].map(|v| {
                    if slot[v] == usize::MAX {
                        slot[v] = own_vertices.len();
                        own_vertices.push(vertices[v]);
                    }
                    slot[v]
                });
                own_edges.push((a, b, weight));
            }
            leaves.push(Self::leaf(
                &own_vertices,
                &own_edges,
                first_vertex..own_vertices.len(),
                first_edge..own_edges.len(),
            ));
        }
        let mut nodes = Vec::with_capacity(2 * leaves.len());
        if !leaves.is_empty() {
            let all: Vec<usize> = (0..leaves.len()).collect();
            Self::build(&mut leaves.into_iter().map(Some).collect::<Vec<_>>(), all, &mut nodes);
        }
        FarField {
            nodes,
            vertices: own_vertices,
            edges: own_edges,
        }
    }

    /// One loop's node: its fan from the mean of its vertices.
    fn leaf(
        vertices: &[DVec3],
        edges: &[(usize, usize, i32)],
        own_vertices: std::ops::Range<usize>,
        own_edges: std::ops::Range<usize>,
    ) -> Node {
        let own = &vertices[own_vertices.clone()];
        let centre = own.iter().sum::<DVec3>() / own.len() as f64;
        let (mut moment, mut area) = (DVec3::ZERO, 0.0);
        // Closed where every vertex has as many edges in as out, weights counted.
        let mut balance = vec![0i64; own.len()];
        for &(a, b, weight) in &edges[own_edges.clone()] {
            let twice = (vertices[a] - centre).cross(vertices[b] - centre);
            moment += 0.5 * f64::from(weight) * twice;
            area += 0.5 * f64::from(weight.unsigned_abs()) * twice.length();
            balance[a - own_vertices.start] -= i64::from(weight);
            balance[b - own_vertices.start] += i64::from(weight);
        }
        let radius = own.iter().map(|&p| (p - centre).length()).fold(0.0, f64::max);
        let (lo, hi) = point_bounds(own.iter().copied());
        Node {
            centre,
            moment,
            area,
            radius,
            lo: lo.truncate(),
            hi: hi.truncate(),
            closed: balance.iter().all(|&b| b == 0),
            children: Children::Loop {
                vertices: own_vertices,
                edges: own_edges,
            },
        }
    }

    /// The subtree over `loops` (indices into `leaves`, each taken once), split at the median
    /// of their centres along their widest axis; returns its root's index in `nodes`.
    fn build(leaves: &mut [Option<Node>], mut loops: Vec<usize>, nodes: &mut Vec<Node>) -> usize {
        if let [only] = loops[..] {
            nodes.push(leaves[only].take().expect("each loop is placed once"));
            return nodes.len() - 1;
        }
        let centre = |l: usize| leaves[l].as_ref().expect("not placed yet").centre;
        let (lo, hi) = point_bounds(loops.iter().map(|&l| centre(l)));
        let axis = (hi - lo).max_position();
        let half = loops.len() / 2;
        loops.select_nth_unstable_by(half, |&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]));
        let upper = loops.split_off(half);
        let (a, b) = (Self::build(leaves, loops, nodes), Self::build(leaves, upper, nodes));
        let (na, nb) = (&nodes[a], &nodes[b]);
        let centre = 0.5 * (na.centre + nb.centre);
        let reach = |n: &Node| (n.centre - centre).length() + n.radius;
        nodes.push(Node {
            centre,
            moment: na.moment + nb.moment,
            area: na.area + nb.area,
            radius: reach(na).max(reach(nb)),
            lo: na.lo.min(nb.lo),
            hi: na.hi.max(nb.hi),
            closed: na.closed && nb.closed,
            children: Children::Split(a, b),
        });
        nodes.len() - 1
    }

    /// For points within the box [lo, hi]: the nodes whose dipoles stand for them at every
    /// point, and the edges of the loops left, which are summed exactly.
    pub(super) fn split(&self, lo: DVec3, hi: DVec3) -> Split {
        let mut split = Split {
            near_vertices: Vec::new(),
            near_edges: Vec::new(),
            far: Vec::new(),
        };
        if let Some(root) = self.nodes.len().checked_sub(1) {
            self.gather(root, lo, hi, &mut split);
        }
        split
    }

    fn gather(&self, n: usize, lo: DVec3, hi: DVec3, split: &mut Split) {
        let node = &self.nodes[n];
        let apart = hi.x < node.lo.x || node.hi.x < lo.x || hi.y < node.lo.y || node.hi.y < lo.y;
        let gap = (lo - node.centre).max(node.centre - hi).max(DVec3::ZERO);
        if node.closed && apart && gap.length() > FAR * node.radius {
            split.far.push(n);
            return;
        }
        match node.children {
            Children::Loop {
                ref vertices,
                ref edges,
            } => {
                // Vertices numbered from where they land in the near list.
                let first = split.near_vertices.len();
                let moved = |v: usize| v - vertices.start + first;
                split.near_vertices.extend_from_slice(&self.vertices[vertices.clone()]);
                let near = self.edges[edges.clone()]
                    .iter()
                    .map(|&(a, b, w)| (moved(a), moved(b), w));
                split.near_edges.extend(near);
            }
            Children::Split(a, b) => {
                self.gather(a, lo, hi, split);
                self.gather(b, lo, hi, split);
            }
        }
    }

    /// The far nodes' share of the curtain term at each of `points` (each within the box the
    /// split was made for), added to `terms`, and their error bound, added to `bounds`.
    pub(super) fn add_far(&self, split: &Split, points: &[DVec3], terms: &mut [f64], bounds: &mut [f64]) {
        for &n in &split.far {
            let node = &self.nodes[n];
            for ((p, term), bound) in points.iter().zip(terms.iter_mut()).zip(bounds.iter_mut()) {
                let d = node.centre - *p;
                let r = d.length();
                *term += node.moment.dot(d) / (r * r * r) / (4.0 * PI);
                *bound += 2.0 * node.area * node.radius / (r - node.radius).powi(3) / (4.0 * PI);
            }
        }
    }
}
