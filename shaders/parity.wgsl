// Parity solid voxelization: every crossing of a column flips the voxels below it (atomicXor
// on the bit grid), so a voxel ends inside when an odd number of crossings lie above it.
// Twin: src/voxel/parity.rs.

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> corners: array<f32>;
@group(0) @binding(2) var<storage, read_write> bits: array<atomic<u32>>;
// (triangle, first column, end column, unused), columns numbered y fastest over the bounds.
@group(0) @binding(4) var<storage, read> items: array<vec4<u32>>;

// Flips bits [start, end).
fn flip_range(start: u32, end: u32) {
    var bit = start;
    while bit < end {
        let word = bit / 32u;
        let first = bit % 32u;
        let last = min(end - word * 32u, 32u);
        let width = last - first;
        var mask = 0xffffffffu;
        if width < 32u {
            mask = ((1u << width) - 1u) << first;
        }
        atomicXor(&bits[word], mask);
        bit = word * 32u + last;
    }
}

@compute @workgroup_size(64)
fn parity(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let id = flat_group(group) * 64u + lane;
    if id >= params.items {
        return;
    }
    let item = items[id];
    let t0 = corner(item.x, 0u);
    let t1 = corner(item.x, 1u);
    let t2 = corner(item.x, 2u);
    let b = slab_bounds(t0, t1, t2);
    for (var i = item.y; i < item.z; i++) {
        let x = b.lo.x + i / b.size.y;
        let y = b.lo.y + i % b.size.y;
        let hit = column_hit(t0, t1, t2, vec2<f32>(f32(x) + 0.5, f32(y) + 0.5));
        if hit.x != 0.0 {
            let start = ((x - params.slab_start) * params.dims_y + y) * params.dims_z;
            flip_range(start, start + voxels_below(hit.y, params.dims_z));
        }
    }
}
