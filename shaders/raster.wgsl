// Depth images of a mesh from orthographic views, rasterized in a compute pass: a thread per
// work item and group of views, where a work item is a triangle and a run of rows of its bounds, the nearest
// depth kept by atomicMax of keys that grow nearer. Pixel centres, edges inclusive, the same sums as the twin,
// `depth_image` in src/eval/raster.rs, so the two agree but for rounding at exact ties. Tiny
// triangles cost a thread each rather than a fixed-function setup each, which is what makes a
// software Vulkan (llvmpipe) fast here.

struct Params {
    pixels: u32,
    views: u32,
    items: u32,
    // Views one thread draws its item in: the corners are loaded once for all of them.
    views_per_thread: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
// Positions relative to the mesh's bounds' centre, three floats a vertex.
@group(0) @binding(1) var<storage, read> positions: array<f32>;
// Three vertex indices a triangle.
@group(0) @binding(2) var<storage, read> triangles: array<u32>;
// (triangle, first row of its bounds, rows, unused).
@group(0) @binding(3) var<storage, read> items: array<vec4<u32>>;
// Three rows a view: (x pixel, y pixel, depth) = row · (position, 1).
@group(0) @binding(4) var<uniform> views: array<vec4<f32>, 768>;
// One image a view, rows from the bottom; depths as `nearness` keys, 0 where empty (so the
// buffer starts zeroed).
@group(0) @binding(5) var<storage, read_write> depth: array<atomic<u32>>;

const GROUPS_X: u32 = 65535u;

fn corner(triangle: u32, k: u32) -> vec3<f32> {
    let v = triangles[3u * triangle + k];
    return vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
}

// Pixel x and y; the depth is projected only for triangles that cover a pixel centre.
fn project(view: u32, p: vec3<f32>) -> vec2<f32> {
    let h = vec4<f32>(p, 1.0);
    return vec2<f32>(dot(views[3u * view], h), dot(views[3u * view + 1u], h));
}

fn depth_at(view: u32, p: vec3<f32>) -> f32 {
    return dot(views[3u * view + 2u], vec4<f32>(p, 1.0));
}

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

// Depths as keys that grow as the depth shrinks, negatives included; none is 0.
fn nearness(d: f32) -> u32 {
    let bits = bitcast<u32>(d);
    return select(~(bits | 0x80000000u), bits, (bits & 0x80000000u) != 0u);
}

@compute @workgroup_size(64)
fn depth_min(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let id = (group.x + group.y * GROUPS_X) * 64u + lane;
    let view_groups = (params.views + params.views_per_thread - 1u) / params.views_per_thread;
    if id >= params.items * view_groups {
        return;
    }
    let item = items[id / view_groups];
    let first_view = (id % view_groups) * params.views_per_thread;
    let c0 = corner(item.x, 0u);
    let c1 = corner(item.x, 1u);
    let c2 = corner(item.x, 2u);
    for (var view = first_view; view < min(first_view + params.views_per_thread, params.views); view++) {
        draw(item, view, c0, c1, c2);
    }
}

fn draw(item: vec4<u32>, view: u32, c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>) {
    let q0 = project(view, c0);
    let q1 = project(view, c1);
    let q2 = project(view, c2);
    // The pixels whose centres lie in the triangle's bounds, as the twin finds them.
    let last_pixel = f32(params.pixels) - 1.0;
    let a = max(min(min(q0, q1), q2) - vec2<f32>(0.5), vec2<f32>(0.0));
    let b = min(max(max(q0, q1), q2) - vec2<f32>(0.5), vec2<f32>(last_pixel));
    if !(a.x <= b.x && a.y <= b.y) {
        return;
    }
    let first = vec2<u32>(ceil(a));
    let last = vec2<u32>(floor(b));
    let area = cross2(q1 - q0, q2 - q0);
    if area == 0.0 {
        return;
    }
    let z = vec3<f32>(depth_at(view, c0), depth_at(view, c1), depth_at(view, c2));
    let n = params.pixels;
    let rows_start = first.y + item.y;
    let rows_end = min(last.y + 1u, rows_start + item.z);
    for (var y = rows_start; y < rows_end; y++) {
        for (var x = first.x; x <= last.x; x++) {
            let c = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
            let w0 = cross2(q2 - q1, c - q1) / area;
            let w1 = cross2(q0 - q2, c - q2) / area;
            let w2 = cross2(q1 - q0, c - q0) / area;
            if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                let key = nearness(w0 * z.x + w1 * z.y + w2 * z.z);
                let pixel = (view * n + y) * n + x;
                // A plain load first: most fragments are behind one already kept.
                if key > atomicLoad(&depth[pixel]) {
                    atomicMax(&depth[pixel], key);
                }
            }
        }
    }
}
