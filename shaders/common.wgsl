// Shared by the voxel stages: the parameters, triangles in voxel units, and the grid ranges.
// Mirrors src/voxel/grid.rs and src/voxel/columns.rs operation for operation, so that the CPU
// twins agree bit for bit.

struct Params {
    dims_x: u32,
    dims_y: u32,
    dims_z: u32,
    // The slab of x layers this dispatch writes: [slab_start, slab_end).
    slab_start: u32,
    slab_end: u32,
    // Work items in this dispatch.
    items: u32,
    boundary_edges: u32,
    // Half a voxel plus slack, in voxel units.
    half: f32,
    // Voxels of a column per `classify` thread.
    segment: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
// Each triangle's corners in voxel units, nine floats a triangle.
@group(0) @binding(1) var<storage, read> corners: array<f32>;
// Work items: (triangle, first unit, end unit, unused); a stage's units are the voxels (z
// fastest) or the columns (y fastest) of the triangle's bounds in the slab.
@group(0) @binding(4) var<storage, read> items: array<vec4<u32>>;

const GROUPS_X: u32 = 65535u;

// llvmpipe (and so lavapipe, Mesa 22) silently ends an invocation's loops after 65535
// iterations in all, so no invocation may loop more: the host splits the work into items that
// stay well below (src/voxel/gpu.rs).

fn flat_group(group: vec3<u32>) -> u32 {
    return group.x + group.y * GROUPS_X;
}

// The voxels of a triangle's bounds within the slab: first voxel and size per axis.
struct Bounds {
    lo: vec3<u32>,
    size: vec3<u32>,
}

fn slab_bounds(t0: vec3<f32>, t1: vec3<f32>, t2: vec3<f32>) -> Bounds {
    let lo = min(min(t0, t1), t2);
    let hi = max(max(t0, t1), t2);
    let xs = voxel_span(lo.x, hi.x, params.dims_x);
    let ys = voxel_span(lo.y, hi.y, params.dims_y);
    let zs = voxel_span(lo.z, hi.z, params.dims_z);
    let x0 = max(xs.x, params.slab_start);
    let x1 = max(min(xs.y, params.slab_end), x0);
    return Bounds(vec3<u32>(x0, ys.x, zs.x), vec3<u32>(x1 - x0, ys.y - ys.x, zs.y - zs.x));
}

struct Work {
    valid: bool,
    t0: vec3<f32>,
    t1: vec3<f32>,
    t2: vec3<f32>,
    bounds: Bounds,
    first: u32,
    end: u32,
}

fn work_item(id: u32) -> Work {
    if id >= params.items {
        return Work(false, vec3<f32>(), vec3<f32>(), vec3<f32>(), Bounds(vec3<u32>(), vec3<u32>()), 0u, 0u);
    }
    let item = items[id];
    let t0 = corner(item.x, 0u);
    let t1 = corner(item.x, 1u);
    let t2 = corner(item.x, 2u);
    return Work(true, t0, t1, t2, slab_bounds(t0, t1, t2), item.y, item.z);
}

fn corner(t: u32, k: u32) -> vec3<f32> {
    let i = 9u * t + 3u * k;
    return vec3<f32>(corners[i], corners[i + 1u], corners[i + 2u]);
}

// The voxels whose closed extent meets [lo, hi] along one axis, clamped to [0, n).
fn voxel_span(lo: f32, hi: f32, n: u32) -> vec2<u32> {
    let start = clamp(i32(floor(lo)) - 1, 0, i32(n));
    let end = clamp(i32(floor(hi)) + 2, 0, i32(n));
    return vec2<u32>(u32(start), u32(end));
}

// (signed area of p against the lexicographically ordered edge, its sign with ties broken),
// both flipped back to the edge a->b.
fn edge_side(a: vec2<f32>, b: vec2<f32>, p: vec2<f32>) -> vec2<f32> {
    var lo = a;
    var hi = b;
    var flip = 1.0;
    if !(a.x < b.x || (a.x == b.x && a.y < b.y)) {
        lo = b;
        hi = a;
        flip = -1.0;
    }
    let area = (hi.x - lo.x) * (p.y - lo.y) - (hi.y - lo.y) * (p.x - lo.x);
    var tie = area;
    if area == 0.0 {
        if hi.y != lo.y {
            tie = -(hi.y - lo.y);
        } else {
            tie = hi.x - lo.x;
        }
    }
    var side = 0.0;
    if tie > 0.0 {
        side = 1.0;
    } else if tie < 0.0 {
        side = -1.0;
    }
    return vec2<f32>(flip * area, flip * side);
}

// Where the vertical line through p meets the triangle: (1 if it does, height, +1 facing up /
// -1 facing down).
fn column_hit(v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>, p: vec2<f32>) -> vec3<f32> {
    let w0 = edge_side(v1.xy, v2.xy, p);
    let w1 = edge_side(v2.xy, v0.xy, p);
    let w2 = edge_side(v0.xy, v1.xy, p);
    let s = w0.y;
    if s == 0.0 || w1.y != s || w2.y != s {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    let total = w0.x + w1.x + w2.x;
    var z = v0.z;
    if total != 0.0 {
        z = divide(w0.x * v0.z + w1.x * v1.z + w2.x * v2.z, total);
    }
    return vec3<f32>(1.0, z, s);
}

// a / b rounded to nearest, as the CPU twin divides: a driver's f32 division may be an ulp off
// (NVIDIA's is), so the quotient and its two neighbours are weighed by their exact remainders,
// ties to even.
fn divide(a: f32, b: f32) -> f32 {
    let q = a / b;
    var best = q;
    var least = abs(remainder(a, b, q));
    for (var i = 0u; i < 2u; i++) {
        let c = bitcast<f32>(select(bitcast<u32>(q) + 1u, bitcast<u32>(q) - 1u, i == 1u));
        let r = abs(remainder(a, b, c));
        if r < least || (r == least && (bitcast<u32>(c) & 1u) == 0u) {
            best = c;
            least = r;
        }
    }
    return best;
}

// a - c * b exactly, for c within a few ulps of a / b: Dekker's product, whose every operation
// must round on its own (the NoContraction the host compiles in).
fn remainder(a: f32, b: f32, c: f32) -> f32 {
    let p = c * b;
    let cs = halves(c);
    let bs = halves(b);
    let e = ((cs.x * bs.x - p) + cs.x * bs.y + cs.y * bs.x) + cs.y * bs.y;
    return (a - p) - e;
}

// x as its upper 12 significant bits and the rest (Veltkamp), so that products of halves are
// exact.
fn halves(x: f32) -> vec2<f32> {
    let t = 4097.0 * x;
    let high = t - (t - x);
    return vec2<f32>(high, x - high);
}

// How many voxel centres of a column lie below height z (k + 0.5 < z).
fn voxels_below(z: f32, n: u32) -> u32 {
    return u32(clamp(i32(ceil(z - 0.5)), 0, i32(n)));
}

// Where column `i` of a work item meets its triangle: the column's first voxel in the slab's
// buffer, the voxels below the crossing and its sign.
struct ColumnCrossing {
    hit: bool,
    start: u32,
    below: u32,
    sign: i32,
}

fn column_crossing(w: Work, i: u32) -> ColumnCrossing {
    let x = w.bounds.lo.x + i / w.bounds.size.y;
    let y = w.bounds.lo.y + i % w.bounds.size.y;
    let hit = column_hit(w.t0, w.t1, w.t2, vec2<f32>(f32(x) + 0.5, f32(y) + 0.5));
    let start = ((x - params.slab_start) * params.dims_y + y) * params.dims_z;
    return ColumnCrossing(hit.x != 0.0, start, voxels_below(hit.y, params.dims_z), i32(hit.z));
}
