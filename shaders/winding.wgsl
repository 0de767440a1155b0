// Generalized winding number w >= 0.5, as in src/voxel/winding.rs: the signed crossings above
// each voxel plus the solid angle of a curtain hung from the open boundary.
// `crossings`: each crossing adds its sign to the highest voxel below it; `above` sums them from
// the top of each column; `classify` adds the curtain term as the CPU twin does (exact every
// STRIDE voxels, interpolated between where that is safe) and sets a bit for inside.

@group(0) @binding(2) var<storage, read_write> sums: array<atomic<i32>>;
// Boundary edges, two rows each: (a, weight), (b, unused). The first UNIFORM_EDGES are in a
// uniform buffer, which a software adapter reads once for all lanes where it reads storage
// lane by lane; the rest, if any, in storage.
const UNIFORM_EDGES: u32 = 2048u;
@group(0) @binding(3) var<uniform> boundary: array<vec4<f32>, 4096>;
@group(0) @binding(6) var<storage, read> more_boundary: array<vec4<f32>>;
// A bit a voxel, set for inside: a 32nd of the bytes to read back that a word a voxel takes.
// Threads share words (columns and runs of a column end mid-word), so bits are set atomically.
@group(0) @binding(5) var<storage, read_write> inside: array<atomic<u32>>;

fn mark_inside(voxel: u32, is_inside: bool) {
    if is_inside {
        atomicOr(&inside[voxel / 32u], 1u << (voxel % 32u));
    }
}

const PI: f32 = 3.14159265358979;

@compute @workgroup_size(64)
fn crossings(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let w = work_item(flat_group(group) * 64u + lane);
    if !w.valid {
        return;
    }
    for (var i = w.first; i < w.end; i++) {
        let c = column_crossing(w, i);
        if c.hit && c.below > 0u {
            atomicAdd(&sums[c.start + c.below - 1u], c.sign);
        }
    }
}

// The solid angle of the triangle (a, b, -z) seen from the origin.
fn curtain_angle(a: vec3<f32>, b: vec3<f32>) -> f32 {
    let la = length(a);
    let lb = length(b);
    let numerator = a.y * b.x - a.x * b.y;
    let denominator = la * lb + dot(a, b) - a.z * lb - b.z * la;
    return 2.0 * atan2(numerator, denominator);
}

fn curtain(p: vec3<f32>) -> f32 {
    var sum = 0.0;
    let edges = params.boundary_edges;
    for (var e = 0u; e < min(edges, UNIFORM_EDGES); e++) {
        let a = boundary[2u * e];
        sum += a.w * curtain_angle(a.xyz - p, boundary[2u * e + 1u].xyz - p);
    }
    for (var e = 0u; e + UNIFORM_EDGES < edges; e++) {
        let a = more_boundary[2u * e];
        sum += a.w * curtain_angle(a.xyz - p, more_boundary[2u * e + 1u].xyz - p);
    }
    return sum / (4.0 * PI);
}

// As in src/voxel/winding.rs.
const STRIDE: u32 = 8u;
const MAX_STEP: f32 = 0.05;
const MARGIN: f32 = 0.15;

// A thread per column: the signed crossings above each voxel, summed from the top.
@compute @workgroup_size(64)
fn above(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let column = flat_group(group) * 64u + lane;
    if column >= (params.slab_end - params.slab_start) * params.dims_y {
        return;
    }
    let start = column * params.dims_z;
    var sum = 0;
    for (var z = i32(params.dims_z) - 1; z >= 0; z--) {
        sum += atomicLoad(&sums[start + u32(z)]);
        atomicStore(&sums[start + u32(z)], sum);
    }
}

// A thread per (column, run of `params.segment` voxels, a multiple of STRIDE): sample the
// curtain at the run's ends and every STRIDE voxels, interpolate between where safe.
@compute @workgroup_size(64)
fn classify(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let id = flat_group(group) * 64u + lane;
    let nz = params.dims_z;
    let segments = (nz - 1u + params.segment - 1u) / params.segment;
    let columns = (params.slab_end - params.slab_start) * params.dims_y;
    if id >= columns * max(segments, 1u) {
        return;
    }
    let column = id / max(segments, 1u);
    let x = f32(params.slab_start + column / params.dims_y) + 0.5;
    let y = f32(column % params.dims_y) + 0.5;
    let start = column * nz;
    if params.boundary_edges == 0u {
        if id % max(segments, 1u) == 0u {
            for (var z = 0u; z < nz; z++) {
                mark_inside(start + z, atomicLoad(&sums[start + z]) >= 1);
            }
        }
        return;
    }
    var z0 = (id % max(segments, 1u)) * params.segment;
    let last = min(z0 + params.segment, nz - 1u);
    var b0 = curtain(vec3<f32>(x, y, f32(z0) + 0.5));
    mark_inside(start + z0, f32(atomicLoad(&sums[start + z0])) + b0 >= 0.5);
    while z0 < last {
        let z1 = min(z0 + STRIDE, last);
        let b1 = curtain(vec3<f32>(x, y, f32(z1) + 0.5));
        let gentle = abs(b1 - b0) < MAX_STEP;
        for (var z = z0 + 1u; z < z1; z++) {
            let count = f32(atomicLoad(&sums[start + z]));
            let estimate = count + b0 + (b1 - b0) * f32(z - z0) / f32(z1 - z0);
            var w = estimate;
            if !(gentle && abs(estimate - 0.5) > MARGIN) {
                w = count + curtain(vec3<f32>(x, y, f32(z) + 0.5));
            }
            mark_inside(start + z, w >= 0.5);
        }
        mark_inside(start + z1, f32(atomicLoad(&sums[start + z1])) + b1 >= 0.5);
        z0 = z1;
        b0 = b1;
    }
}
