// Conservative surface voxelization: a thread per work item (a triangle and a run of the voxels
// of its bounds), the separating-axis test, atomicOr into a bit grid. Twin: src/voxel/surface.rs.

@group(0) @binding(2) var<storage, read_write> bits: array<atomic<u32>>;

fn separated(lo: f32, hi: f32, r: f32) -> bool {
    return lo > r || hi < -r;
}

fn axis_separates(p0: f32, p1: f32, p2: f32, r: f32) -> bool {
    return separated(min(min(p0, p1), p2), max(max(p0, p1), p2), r);
}

// Akenine-Möller's triangle/box test with the box centred at c, written out term by term as in
// the CPU twin.
fn overlaps(c: vec3<f32>, h: f32, t0: vec3<f32>, t1: vec3<f32>, t2: vec3<f32>) -> bool {
    let a = t0 - c;
    let b = t1 - c;
    let d = t2 - c;
    if axis_separates(a.x, b.x, d.x, h) || axis_separates(a.y, b.y, d.y, h) || axis_separates(a.z, b.z, d.z, h) {
        return false;
    }
    let e0 = b - a;
    let e1 = d - b;
    let e2 = a - d;
    let n = vec3<f32>(e0.y * e1.z - e0.z * e1.y, e0.z * e1.x - e0.x * e1.z, e0.x * e1.y - e0.y * e1.x);
    let r = h * abs(n.x) + h * abs(n.y) + h * abs(n.z);
    if abs(n.x * a.x + n.y * a.y + n.z * a.z) > r {
        return false;
    }
    return !(edge_separates(e0, a, b, d, h) || edge_separates(e1, a, b, d, h) || edge_separates(e2, a, b, d, h));
}

// The three axes (x, y, z) cross edge e.
fn edge_separates(e: vec3<f32>, a: vec3<f32>, b: vec3<f32>, d: vec3<f32>, h: f32) -> bool {
    let rx = h * abs(e.y) + h * abs(e.z);
    let ry = h * abs(e.z) + h * abs(e.x);
    let rz = h * abs(e.x) + h * abs(e.y);
    return axis_separates(e.y * a.z - e.z * a.y, e.y * b.z - e.z * b.y, e.y * d.z - e.z * d.y, rx)
        || axis_separates(e.z * a.x - e.x * a.z, e.z * b.x - e.x * b.z, e.z * d.x - e.x * d.z, ry)
        || axis_separates(e.x * a.y - e.y * a.x, e.x * b.y - e.y * b.x, e.x * d.y - e.y * d.x, rz);
}

@compute @workgroup_size(64)
fn surface(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let w = work_item(flat_group(group) * 64u + lane);
    if !w.valid {
        return;
    }
    let b = w.bounds;
    // The item's voxels, z fastest, counted rather than divided out of i each time: a software
    // adapter divides lane by lane.
    var x = b.lo.x + w.first / (b.size.y * b.size.z);
    var y = b.lo.y + (w.first / b.size.z) % b.size.y;
    var z = b.lo.z + w.first % b.size.z;
    for (var i = w.first; i < w.end; i++) {
        let centre = vec3<f32>(f32(x), f32(y), f32(z)) + vec3<f32>(0.5);
        if overlaps(centre, params.half, w.t0, w.t1, w.t2) {
            let bit = ((x - params.slab_start) * params.dims_y + y) * params.dims_z + z;
            atomicOr(&bits[bit / 32u], 1u << (bit % 32u));
        }
        z++;
        if z == b.lo.z + b.size.z {
            z = b.lo.z;
            y++;
            if y == b.lo.y + b.size.y {
                y = b.lo.y;
                x++;
            }
        }
    }
}
