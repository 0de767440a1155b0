// Ground truth of cull-eval: the level's real meshes rendered with a depth test, each pixel
// keeping the id of the instance nearest to the camera. Twin: `ground_truth` in
// src/level/cull.rs.

@group(0) @binding(0) var<uniform> clip_from_level: mat4x4<f32>;

struct Vertex {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) instance: u32,
}

@vertex
fn place(@location(0) position: vec3<f32>, @location(1) instance: u32) -> Vertex {
    return Vertex(clip_from_level * vec4<f32>(position, 1.0), instance);
}

@fragment
fn instance_id(v: Vertex) -> @location(0) u32 {
    return v.instance;
}
