//! Surface pieces: the mesh's own triangles, grouped into connected flat regions, each region's
//! outline triangulated again with as few triangles as it takes (a constrained Delaunay
//! triangulation of the outline's vertices, by spade). A piece lies on the surface, so it hides
//! exactly what that part of the surface hides; a closed part's new triangles lie on it or just
//! under it, where its region bends. Pieces are drawn double-sided, but for a closed part chosen
//! whole, which faces out with the solid; a double-sided piece whose region bends keeps the
//! region's own triangles, as either side may be seen.

use crate::mesh::Mesh;
use crate::mesh::buckets::Buckets;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};
use std::collections::BTreeMap;

/// One flat region of the surface, as triangles.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SurfacePiece {
    pub triangles: Vec<[[f64; 3]; 3]>,
    /// In square world units.
    pub area: f64,
    /// Triangles of the mesh it replaces.
    pub source_triangles: usize,
    /// Whether it is drawn from both sides: where its part of the mesh is open, and wherever its
    /// part is not chosen whole (the faces chosen may cover a view's silhouette from behind).
    pub double_sided: bool,
}

impl SurfacePiece {
    pub fn mesh(&self) -> Mesh {
        pieces_mesh([self])
    }
}

/// Pieces as one triangle mesh.
pub fn pieces_mesh<'a>(pieces: impl IntoIterator<Item = &'a SurfacePiece>) -> Mesh {
    let corners: Vec<glam::Vec3> = pieces
        .into_iter()
        .flat_map(|p| p.triangles.iter().flatten())
        .map(|c| DVec3::from_array(*c).as_vec3())
        .collect();
    Mesh {
        triangles: (0..corners.len() as u32 / 3)
            .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
            .collect(),
        positions: corners,
    }
}

/// Every flat region of the mesh as a piece, largest first; `open_triangles` marks the triangles
/// of open parts. Triangles join a region when their corners lie within `tolerance` of its first
/// triangle's plane and they face the same way, so that a piece never leaves the surface by more
/// than twice that.
pub fn find(mesh: &Mesh, open_triangles: &[bool], tolerance: f64) -> Vec<SurfacePiece> {
    let regions = flat_regions(mesh, tolerance);
    let mut pieces: Vec<SurfacePiece> = regions
        .par_iter()
        .map(|r| piece_of(mesh, r, open_triangles[r[0]], tolerance))
        .collect();
    pieces.par_sort_by(|a, b| b.area.total_cmp(&a.area));
    pieces
}

fn normal(mesh: &Mesh, t: usize) -> Option<DVec3> {
    let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
    (b - a).cross(c - a).try_normalize()
}

/// Connected regions of triangles that share edges and lie in one plane, each listed from its
/// first triangle; degenerate triangles join none.
fn flat_regions(mesh: &Mesh, tolerance: f64) -> Vec<Vec<usize>> {
    // Per vertex, the triangles that use it, in order: the triangles across an edge are those of
    // its first end that also use its second.
    let users = Buckets::new(
        mesh.positions.len(),
        mesh.triangles
            .iter()
            .enumerate()
            .flat_map(|(t, tri)| tri.iter().map(move |&v| (v as usize, t as u32))),
    );
    let normals: Vec<Option<DVec3>> = (0..mesh.triangles.len())
        .into_par_iter()
        .map(|t| normal(mesh, t))
        .collect();
    let mut region_of = vec![false; mesh.triangles.len()];
    let mut regions = Vec::new();
    for seed in 0..mesh.triangles.len() {
        let Some(n) = normals[seed] else { continue };
        if region_of[seed] {
            continue;
        }
        let offset = n.dot(mesh.positions[mesh.triangles[seed][0] as usize].as_dvec3());
        let in_plane = |t: usize| {
            normals[t].is_some_and(|m| m.dot(n) > 0.0)
                && mesh.triangles[t]
                    .iter()
                    .all(|&v| (n.dot(mesh.positions[v as usize].as_dvec3()) - offset).abs() <= tolerance)
        };
        region_of[seed] = true;
        let mut region = vec![seed];
        let mut next = 0;
        while next < region.len() {
            let tri = mesh.triangles[region[next]];
            next += 1;
            for k in 0..3 {
                let (a, b) = (tri[k] as usize, tri[(k + 1) % 3]);
                for &u in users.get(a) {
                    let u = u as usize;
                    if !region_of[u] && mesh.triangles[u].contains(&b) && in_plane(u) {
                        region_of[u] = true;
                        region.push(u);
                    }
                }
            }
        }
        regions.push(region);
    }
    regions
}

/// The region as one piece: its outline triangulated again where that takes fewer triangles,
/// else its own triangles.
fn piece_of(mesh: &Mesh, region: &[usize], double_sided: bool, tolerance: f64) -> SurfacePiece {
    let area: f64 = region
        .iter()
        .map(|&t| {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            0.5 * (b - a).cross(c - a).length()
        })
        .sum();
    let own = || -> Vec<[[f64; 3]; 3]> {
        region
            .iter()
            .map(|&t| mesh.corners(t).map(|p| p.as_dvec3().to_array()))
            .collect()
    };
    // A double-sided piece is seen from both sides, so new triangles that span where the region
    // bends would stand in front of it from one; only an exactly flat region's are kept.
    let triangles = match region.len() {
        1 => own(),
        _ if double_sided && !lies_flat(mesh, region, tolerance * 1e-3) => own(),
        _ => retriangulate(mesh, region, tolerance)
            .filter(|t| t.len() < region.len())
            .map(|t| if double_sided { t } else { under_region(mesh, region, t) })
            .unwrap_or_else(own),
    };
    SurfacePiece {
        triangles,
        area,
        source_triangles: region.len(),
        double_sided,
    }
}

/// The heights of the region's corners along `n`.
fn heights_along(mesh: &Mesh, region: &[usize], n: DVec3) -> impl Iterator<Item = f64> {
    region
        .iter()
        .flat_map(|&t| mesh.corners(t))
        .map(move |p| n.dot(p.as_dvec3()))
}

/// Whether every corner of the region lies within `within` of its first triangle's plane.
fn lies_flat(mesh: &Mesh, region: &[usize], within: f64) -> bool {
    let Some(n) = normal(mesh, region[0]) else {
        return false;
    };
    let offset = n.dot(mesh.corners(region[0])[0].as_dvec3());
    heights_along(mesh, region, n).all(|h| (h - offset).abs() <= within)
}

/// A closed part's new triangles, moved in along the normal of the region's first triangle
/// until none stands above the region's lowest corner. They span corners that the region's own
/// triangles bend between (within the tolerance); where the region dips, they would stand
/// outside the solid, and a grazing view shows that past the surface, however small. Below the
/// lowest corner they lie under the region everywhere. An exactly flat region's stay put.
fn under_region(mesh: &Mesh, region: &[usize], triangles: Vec<[[f64; 3]; 3]>) -> Vec<[[f64; 3]; 3]> {
    let Some(n) = normal(mesh, region[0]) else {
        return triangles;
    };
    let lowest = heights_along(mesh, region, n).fold(f64::INFINITY, f64::min);
    let highest = triangles
        .iter()
        .flatten()
        .map(|&c| n.dot(DVec3::from_array(c)))
        .fold(f64::NEG_INFINITY, f64::max);
    let drop = n * (highest - lowest).max(0.0);
    triangles
        .into_iter()
        .map(|t| t.map(|c| (DVec3::from_array(c) - drop).to_array()))
        .collect()
}

/// The region's outline, triangulated with a constrained Delaunay triangulation of its vertices;
/// None where it cannot be done exactly (crossing or overlapping edges, corners that meet in the
/// plane), so that a piece never covers what the region does not.
fn retriangulate(mesh: &Mesh, region: &[usize], tolerance: f64) -> Option<Vec<[[f64; 3]; 3]>> {
    let frame = Frame::of(mesh, region[0]);
    let flat = |v: u32| frame.flat(mesh.positions[v as usize].as_dvec3());
    let mut outline = Outline::of(mesh, region);
    // Straightening only drops corners that lie on a line to well within the tolerance.
    outline.straighten(&flat, tolerance * 1e-3);
    let triangles2d: Vec<[DVec2; 3]> = region.iter().map(|&t| mesh.triangles[t].map(flat)).collect();
    // Two triangles are worth a new triangulation only where it gives one.
    if region.len() == 2 && !one_triangle_may_do(&outline, &flat, area(&triangles2d)) {
        return None;
    }
    triangulate(mesh, &outline, &flat, &triangles2d)
}

/// [`retriangulate`]'s triangulation of the straightened `outline` of the region whose
/// triangles, in the plane, are `triangles2d`.
fn triangulate(
    mesh: &Mesh,
    outline: &Outline,
    flat: &impl Fn(u32) -> DVec2,
    triangles2d: &[[DVec2; 3]],
) -> Option<Vec<[[f64; 3]; 3]>> {
    let mut cdt: ConstrainedDelaunayTriangulation<Point2<f64>> = ConstrainedDelaunayTriangulation::new();
    // In a fixed order: where corners lie on one circle (a rectangle's), the order of insertion
    // picks the triangulation.
    let corners: Vec<u32> = outline.neighbours.keys().copied().collect();
    let mut vertex_of_handle: Vec<Option<u32>> = vec![None; corners.len()];
    let mut handles = Vec::with_capacity(corners.len());
    for &v in &corners {
        let p = flat(v);
        let handle = cdt.insert(Point2::new(p.x, p.y)).ok()?;
        // A handle met before is a corner at the same point as another.
        if vertex_of_handle[handle.index()].replace(v).is_some() {
            return None;
        }
        handles.push(handle);
    }
    let handle_of = |v: u32| handles[corners.binary_search(&v).expect("an outline corner")];
    for (a, b) in outline.edges() {
        let (ha, hb) = (handle_of(a), handle_of(b));
        if !cdt.can_add_constraint(ha, hb) {
            return None;
        }
        cdt.add_constraint(ha, hb);
    }
    let mut kept = Vec::new();
    let mut kept_area = 0.0;
    let bins = TriangleBins::new(triangles2d);
    for face in cdt.inner_faces() {
        let corners = face
            .vertices()
            .map(|v| vertex_of_handle[v.fix().index()].expect("an inserted corner"));
        let q = corners.map(flat);
        let centroid = (q[0] + q[1] + q[2]) / 3.0;
        if bins.any_contains(centroid) {
            kept_area += triangle_area(&q);
            kept.push(corners.map(|v| mesh.positions[v as usize].as_dvec3().to_array()));
        }
    }
    // Every face lies wholly inside or outside when the whole outline is in the triangulation:
    // then the kept area is the region's.
    let region_area = area(triangles2d);
    ((kept_area - region_area).abs() <= 1e-9 * region_area.max(f64::MIN_POSITIVE)).then_some(kept)
}

/// The area of triangles in the plane.
fn area(triangles: &[[DVec2; 3]]) -> f64 {
    triangles.iter().map(triangle_area).sum()
}

fn triangle_area(q: &[DVec2; 3]) -> f64 {
    cross(q[1] - q[0], q[2] - q[0]).abs() / 2.0
}

/// Whether a triangulation of an outline of four corners can keep a single triangle, one on
/// three of them whose area is the region's (`area`) to the billionth [`triangulate`] allows:
/// not where each such triangle's area misses it by two billionths and by far more than
/// rounding can move either. Any other outline, with three corners or more than four, may.
fn one_triangle_may_do(outline: &Outline, flat: &impl Fn(u32) -> DVec2, area: f64) -> bool {
    let corners: Vec<DVec2> = outline.neighbours.keys().map(|&v| flat(v)).collect();
    if corners.len() != 4 {
        return true;
    }
    let size = corners.iter().map(|c| c.x.abs() + c.y.abs()).fold(0.0, f64::max);
    let rounding = 1e-12 * size * size;
    (0..4).any(|left_out| {
        let q: [DVec2; 3] = std::array::from_fn(|k| corners[k + usize::from(k >= left_out)]);
        (triangle_area(&q) - area).abs() <= 2e-9 * area + rounding
    })
}

/// Triangles in the plane, listed in the bins of a grid over their bounds (about one bin a
/// triangle) that their own bounds meet: where a point lies, those of its bin are tried first.
struct TriangleBins<'a> {
    triangles: &'a [[DVec2; 3]],
    grid: BinGrid,
    bins: Buckets<u32>,
}

/// `side` × `side` bins from `lo`, `per_unit` bins per unit length along each axis.
#[derive(Clone, Copy)]
struct BinGrid {
    lo: DVec2,
    per_unit: DVec2,
    side: usize,
}

impl BinGrid {
    /// The bin of a point, those beyond the grid in the nearest.
    fn place(&self, p: DVec2) -> [usize; 2] {
        // A cast saturates, and takes NaN to 0.
        let at = ((p - self.lo) * self.per_unit).to_array();
        at.map(|x| (x as usize).min(self.side - 1))
    }
}

impl<'a> TriangleBins<'a> {
    fn new(triangles: &'a [[DVec2; 3]]) -> TriangleBins<'a> {
        let bounds = |t: &[DVec2; 3]| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
        let (lo, hi) = triangles
            .iter()
            .map(bounds)
            .fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(lo, hi), (a, b)| {
                (lo.min(a), hi.max(b))
            });
        let side = (triangles.len() as f64).sqrt().ceil().max(1.0) as usize;
        let per_unit = (hi - lo).map(|e| if e > 0.0 { side as f64 / e } else { 0.0 });
        let grid = BinGrid { lo, per_unit, side };
        let bins = Buckets::new(
            side * side,
            triangles.iter().enumerate().flat_map(move |(i, t)| {
                let (a, b) = bounds(t);
                let ([x0, y0], [x1, y1]) = (grid.place(a), grid.place(b));
                (x0..=x1).flat_map(move |x| (y0..=y1).map(move |y| (x * side + y, i as u32)))
            }),
        );
        TriangleBins { triangles, grid, bins }
    }

    /// Whether any triangle contains `p` ([`contains`]): the answer of trying them all, as it
    /// tries them all where none of its bin does.
    fn any_contains(&self, p: DVec2) -> bool {
        let [x, y] = self.grid.place(p);
        let first = self.bins.get(x * self.grid.side + y);
        first.iter().any(|&i| contains(&self.triangles[i as usize], p)) || self.triangles.iter().any(|t| contains(t, p))
    }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

fn contains(t: &[DVec2; 3], p: DVec2) -> bool {
    let area = cross(t[1] - t[0], t[2] - t[0]);
    (0..3).all(|k| cross(t[(k + 1) % 3] - t[k], p - t[k]) * area.signum() >= 0.0)
}

/// Coordinates in a triangle's plane, from its first corner.
struct Frame {
    origin: DVec3,
    e1: DVec3,
    e2: DVec3,
}

impl Frame {
    fn of(mesh: &Mesh, t: usize) -> Frame {
        let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
        let n = (b - a).cross(c - a).normalize();
        let e1 = (b - a).normalize();
        Frame {
            origin: a,
            e1,
            e2: n.cross(e1),
        }
    }

    fn flat(&self, p: DVec3) -> DVec2 {
        let d = p - self.origin;
        DVec2::new(d.dot(self.e1), d.dot(self.e2))
    }
}

/// The edges that only one triangle of a region uses, as each corner's neighbours along them,
/// the corners in order.
struct Outline {
    neighbours: BTreeMap<u32, Vec<u32>>,
}

impl Outline {
    fn of(mesh: &Mesh, region: &[usize]) -> Outline {
        let mut edges: Vec<(u32, u32)> = region
            .iter()
            .flat_map(|&t| {
                let tri = mesh.triangles[t];
                (0..3).map(move |k| (tri[k].min(tri[(k + 1) % 3]), tri[k].max(tri[(k + 1) % 3])))
            })
            .collect();
        edges.sort_unstable();
        let mut neighbours: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for uses in edges.chunk_by(|x, y| x == y).filter(|uses| uses.len() == 1) {
            let (a, b) = uses[0];
            neighbours.entry(a).or_default().push(b);
            neighbours.entry(b).or_default().push(a);
        }
        Outline { neighbours }
    }

    /// Each edge once.
    fn edges(&self) -> Vec<(u32, u32)> {
        let mut edges: Vec<(u32, u32)> = self
            .neighbours
            .iter()
            .flat_map(|(&a, ns)| ns.iter().filter(move |&&b| a < b).map(move |&b| (a, b)))
            .collect();
        edges.sort_unstable();
        edges
    }

    /// Drops corners where the outline runs straight on (within `straight` of the line between
    /// its neighbours, and between them), joining the neighbours.
    fn straighten(&mut self, flat: &impl Fn(u32) -> DVec2, straight: f64) {
        let corners: Vec<u32> = self.neighbours.keys().copied().collect();
        for v in corners {
            let [p, q] = match self.neighbours[&v][..] {
                [p, q] => [p, q],
                _ => continue,
            };
            if self.neighbours[&p].contains(&q) {
                continue;
            }
            let (a, b, c) = (flat(p), flat(v), flat(q));
            let along = c - a;
            let length = along.length();
            let t = (b - a).dot(along);
            if length == 0.0 || t <= 0.0 || t >= length * length || cross(along, b - a).abs() > straight * length {
                continue;
            }
            self.neighbours.remove(&v);
            for (from, to) in [(p, q), (q, p)] {
                let ns = self.neighbours.get_mut(&from).expect("a neighbour is a corner");
                let slot = ns.iter().position(|&n| n == v).expect("neighbours both ways");
                ns[slot] = to;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn two_triangles_skip_the_triangulation_only_where_it_gives_two_or_more() {
        let mut rng = fastrand::Rng::with_seed(11);
        let (mut one, mut skipped) = (0, 0);
        for round in 0..20_000 {
            // P, Q and Y, and X left of PQ: on it (exactly, on a grid that f32 holds), near it,
            // near P or Q, or anywhere.
            let exact = round % 4 == 3;
            let point = |rng: &mut fastrand::Rng| match exact {
                true => glam::DVec2::new(rng.i32(-8..=8) as f64, rng.i32(-8..=8) as f64) / 8.0,
                false => glam::DVec2::new(rng.f64() * 2.0 - 1.0, rng.f64() * 2.0 - 1.0),
            };
            let (p, q) = (point(&mut rng), point(&mut rng));
            let along = q - p;
            let left = glam::DVec2::new(-along.y, along.x);
            let s = [
                rng.f64(),
                -0.2 * rng.f64(),
                1.0 + 0.2 * rng.f64(),
                rng.usize(1..4) as f64 / 4.0,
            ][round % 4];
            let off = [0.0, 1e-7, 1e-6, 1e-5, 1e-3, 0.3][rng.usize(0..6)] * rng.f64();
            let x = p + along * s + left * if exact { 0.0 } else { off };
            let y = p + along * rng.f64() - left * (0.05 + rng.f64());
            // The first, whose plane the frame takes, never degenerate.
            let mesh = Mesh {
                positions: [p, q, x, y]
                    .iter()
                    .map(|c| Vec3::new(c.x as f32, c.y as f32, 0.0))
                    .collect(),
                triangles: vec![[1, 0, 3], [0, 1, 2]],
            };
            let region = [0, 1];
            let frame = Frame::of(&mesh, 0);
            let flat = |v: u32| frame.flat(mesh.positions[v as usize].as_dvec3());
            let mut outline = Outline::of(&mesh, &region);
            // A millionth: above the rounding of the corners to f32.
            outline.straighten(&flat, 1e-3 * 1e-3);
            let fewer = |t: Option<Vec<[[f64; 3]; 3]>>| t.filter(|t| t.len() < 2);
            let triangles2d = region.map(|t| mesh.triangles[t].map(flat));
            let whole = fewer(triangulate(&mesh, &outline, &flat, &triangles2d));
            assert_eq!(fewer(retriangulate(&mesh, &region, 1e-3)), whole, "round {round}");
            one += usize::from(whole.is_some());
            skipped += usize::from(!one_triangle_may_do(&outline, &flat, area(&triangles2d)));
        }
        assert!(
            one > 2_000 && skipped > 10_000,
            "{one} as one triangle, {skipped} skipped"
        );
    }

    #[test]
    fn triangles_tried_by_bin_first_contain_a_point_where_trying_them_all_does() {
        let mut rng = fastrand::Rng::with_seed(5);
        let point = |rng: &mut fastrand::Rng| DVec2::new(rng.f64() * 10.0, rng.f64() * 4.0);
        let triangles: Vec<[DVec2; 3]> = (0..200)
            .map(|_| {
                let a = point(&mut rng);
                [
                    a,
                    a + DVec2::new(rng.f64(), rng.f64()),
                    a + DVec2::new(-rng.f64(), rng.f64()),
                ]
            })
            .collect();
        let bins = TriangleBins::new(&triangles);
        let mut inside = 0;
        for _ in 0..5_000 {
            let p = point(&mut rng) * 1.2 - DVec2::splat(0.5);
            let all = triangles.iter().any(|t| contains(t, p));
            assert_eq!(bins.any_contains(p), all, "{p}");
            inside += usize::from(all);
        }
        assert!((500..4_500).contains(&inside), "{inside} inside");
        // Rounding lets a sliver contain a point a step of a float past its corner, at x = 2,
        // across the line between bins there: 13 triangles over x in [0, 4] make 4 × 4 bins.
        let sliver = [
            DVec2::new(2.0, 0.9892988659132093),
            DVec2::new(3.7352113129209097, 2.8478306551494548),
            DVec2::new(3.569838707079753, 2.6707051127235966),
        ];
        let past = DVec2::new(1.9999999999999998, 0.9892988659132091);
        let small = |x: f64| [DVec2::new(x, 3.5), DVec2::new(x + 0.25, 3.5), DVec2::new(x, 3.75)];
        let mut triangles = vec![sliver];
        triangles.extend((0..12).map(|k| small(k as f64 * 3.75 / 11.0)));
        let bins = TriangleBins::new(&triangles);
        assert!(contains(&sliver, past) && bins.grid.place(past)[0] == 1 && bins.grid.place(sliver[0])[0] == 2);
        assert!(bins.any_contains(past));
    }

    /// An n×n grid of squares, two triangles each, on z = 0.
    fn grid(n: u32) -> Mesh {
        let mut mesh = Mesh::default();
        for y in 0..=n {
            for x in 0..=n {
                mesh.positions.push(Vec3::new(x as f32, y as f32, 0.0));
            }
        }
        let at = |x: u32, y: u32| y * (n + 1) + x;
        for y in 0..n {
            for x in 0..n {
                mesh.triangles.push([at(x, y), at(x + 1, y), at(x + 1, y + 1)]);
                mesh.triangles.push([at(x, y), at(x + 1, y + 1), at(x, y + 1)]);
            }
        }
        mesh
    }

    #[test]
    fn a_tessellated_square_becomes_two_triangles_of_the_same_area() {
        let pieces = find(&grid(8), &[true; 128], 1e-6);
        assert_eq!(pieces.len(), 1);
        assert_eq!(pieces[0].source_triangles, 128);
        assert_eq!(pieces[0].triangles.len(), 2);
        assert!((pieces[0].area - 64.0).abs() < 1e-9);
    }

    #[test]
    fn a_square_with_a_hole_keeps_its_hole() {
        let mut mesh = grid(3);
        // The middle square's two triangles go.
        mesh.triangles.drain(8..10);
        let pieces = find(&mesh, &[true; 32], 1e-6);
        assert_eq!(pieces.len(), 1);
        let p = &pieces[0];
        // An outline of 4 corners with a hole of 4: 4 + 4 + 2 - 2 triangles.
        assert_eq!(p.triangles.len(), 8);
        let area: f64 = p
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(DVec3::from_array);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        assert!((area - 8.0).abs() < 1e-9, "{area}");
        // No triangle covers the hole's centre.
        let centre = DVec2::new(1.5, 1.5);
        for t in &p.triangles {
            let q = t.map(|c| DVec2::new(c[0], c[1]));
            assert!(!contains(&q, centre), "{t:?}");
        }
    }

    #[test]
    fn a_closed_parts_piece_lies_under_a_region_that_dips() {
        let mut mesh = grid(4);
        // The first triangle stays flat; the other inner corners dip by well within the tolerance.
        for (v, p) in mesh.positions.iter_mut().enumerate() {
            let (x, y) = (v % 5, v / 5);
            if (1..4).contains(&x) && (1..4).contains(&y) && (x, y) != (1, 1) {
                p.z = -1e-7;
            }
        }
        let lowest = mesh.positions.iter().map(|p| f64::from(p.z)).fold(0.0, f64::min);
        let closed = find(&mesh, &[false; 32], 1e-6);
        assert_eq!((closed.len(), closed[0].triangles.len()), (1, 2));
        for c in closed[0].triangles.iter().flatten() {
            assert!(c[2] <= lowest, "{c:?} above {lowest}");
        }
        // An open part's piece has no inside to go to, and is seen from both sides: where its
        // region bends, it keeps the region's own triangles. An exactly flat one stays put.
        let open = find(&mesh, &[true; 32], 1e-6);
        assert_eq!(open[0].triangles.len(), 32);
        assert!(mesh.triangles.iter().all(|t| {
            let own = t.map(|v| mesh.positions[v as usize].as_dvec3().to_array());
            open[0].triangles.contains(&own)
        }));
        for side in [false, true] {
            let flat = find(&grid(4), &[side; 32], 1e-6);
            assert_eq!(flat[0].triangles.len(), 2);
            assert!(flat[0].triangles.iter().flatten().all(|c| c[2] == 0.0));
        }
    }

    #[test]
    fn a_fold_or_a_step_starts_a_new_region() {
        let mut mesh = grid(2);
        // Lift one corner off the plane: the two triangles that use it leave the region.
        let corner = mesh.positions.len() - 1;
        mesh.positions[corner].z = 0.5;
        let pieces = find(&mesh, &[true; 32], 1e-6);
        assert!(pieces.len() >= 2, "{pieces:?}");
        let flat = &pieces[0];
        assert_eq!(flat.source_triangles, 6);
        for c in flat.triangles.iter().flatten() {
            assert_eq!(c[2], 0.0);
        }
    }
}
