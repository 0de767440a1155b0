// Parity solid voxelization: every crossing of a column flips the voxels below it (atomicXor
// on the bit grid), so a voxel ends inside when an odd number of crossings lie above it.
// Twin: src/voxel/parity.rs.

@group(0) @binding(2) var<storage, read_write> bits: array<atomic<u32>>;

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
    let w = work_item(flat_group(group) * 64u + lane);
    if !w.valid {
        return;
    }
    for (var i = w.first; i < w.end; i++) {
        let c = column_crossing(w, i);
        if c.hit {
            flip_range(c.start, c.start + c.below);
        }
    }
}
