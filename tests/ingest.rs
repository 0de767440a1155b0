//! Ingest: each format from bytes built here, the lenient readings, and the rejections.

mod common;
use common::cuboid;
use glam::Vec3;
use occluder_cook::mesh::{Format, IngestError, IngestLimits, glb, load_bytes, load_file};
use occluder_cook::occluder::Shape;

fn obj_cube() -> String {
    let m = cuboid(Vec3::ZERO, Vec3::ONE, &[]);
    let mut s = String::from("o cube\n");
    for p in &m.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &m.triangles {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

fn binary_stl(triangles: &[[Vec3; 3]], header: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..header.len()].copy_from_slice(header);
    out.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
    for t in triangles {
        out.extend_from_slice(&[0u8; 12]);
        for v in t {
            for c in v.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

#[test]
fn obj_and_glb_and_stl_give_the_same_welded_cube() {
    let (from_obj, stats) = load_bytes(obj_cube().as_bytes(), Format::Obj, None, &IngestLimits::default()).unwrap();
    assert_eq!((from_obj.triangles.len(), stats.welded_vertices), (12, 8));
    let part = glb::Part {
        name: "cube",
        mesh: &from_obj,
        double_sided: false,
    };
    let glb_bytes = glb::write(&[part], serde_json::json!({}));
    let (from_glb, _) = load_bytes(&glb_bytes, Format::Gltf, None, &IngestLimits::default()).unwrap();
    assert_eq!(from_glb.triangles, from_obj.triangles);
    let soup: Vec<[Vec3; 3]> = (0..12).map(|t| from_obj.corners(t)).collect();
    // A binary header that starts with "solid" is still binary: the size says so.
    let (from_stl, stats) = load_bytes(
        &binary_stl(&soup, b"solid but binary"),
        Format::Stl,
        None,
        &IngestLimits::default(),
    )
    .unwrap();
    assert_eq!(
        (from_stl.triangles.len(), stats.welded_vertices, stats.input_vertices),
        (12, 8, 36)
    );
    let settings = common::defaults();
    let key = |m| occluder_cook::key::cache_key(&m, &settings.cook);
    assert_eq!(key(from_obj.clone()), key(from_stl));
    assert_eq!(key(from_obj), key(from_glb));
}

#[test]
fn gltf_strips_fans_transforms_and_skipped_lines() {
    // One quad as a strip under a node scaled by 2, one as a fan, and a line primitive.
    let positions: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    let bin: Vec<u8> = positions.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
    let uri = format!("data:application/octet-stream;base64,{}", base64_encode(&bin));
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "scale": [2.0, 2.0, 2.0]}, {"mesh": 1, "translation": [5.0, 0.0, 0.0]}],
        "buffers": [{"byteLength": 48, "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 48}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "mode": 5}, {"attributes": {"POSITION": 0}, "mode": 1}]},
            {"primitives": [{"attributes": {"POSITION": 0}, "mode": 6}]}
        ]
    });
    let (mesh, stats) = load_bytes(doc.to_string().as_bytes(), Format::Gltf, None, &IngestLimits::default()).unwrap();
    assert_eq!(stats.skipped_primitives, 1);
    assert_eq!(mesh.triangles.len(), 4);
    let (lo, hi) = mesh.bounds();
    assert_eq!((lo, hi), (Vec3::ZERO, Vec3::new(6.0, 2.0, 0.0)));
}

fn base64_encode(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

#[test]
fn bad_inputs_are_rejected_with_one_line_messages() {
    let cases: Vec<(&str, Format, Vec<u8>)> = vec![
        ("nan", Format::Obj, b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n".to_vec()),
        (
            "out of bounds",
            Format::Obj,
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec(),
        ),
        ("no triangles", Format::Obj, b"v 0 0 0\n".to_vec()),
        (
            "degenerate",
            Format::Obj,
            b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n".to_vec(),
        ),
        ("empty", Format::Stl, Vec::new()),
        ("truncated", Format::Stl, {
            let mut b = binary_stl(&[[Vec3::ZERO, Vec3::X, Vec3::Y]], b"x");
            b.truncate(100);
            b
        }),
        (
            "ends inside facet",
            Format::Stl,
            b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n".to_vec(),
        ),
        ("malformed glTF", Format::Gltf, b"{not json".to_vec()),
    ];
    for (what, format, bytes) in cases {
        let err = load_bytes(&bytes, format, None, &IngestLimits::default())
            .expect_err(what)
            .to_string();
        assert!(!err.contains('\n'), "{what}: {err}");
        println!("{what}: {err}");
    }
}

#[test]
fn cyclic_gltf_nodes_are_rejected() {
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"children": [1]}, {"children": [0]}]
    });
    match load_bytes(doc.to_string().as_bytes(), Format::Gltf, None, &IngestLimits::default()) {
        Err(e) => assert!(e.to_string().contains("cycle"), "{e}"),
        Ok(_) => panic!("a cyclic node graph was accepted"),
    }
}

/// ../shared/meshes/broken, as its EXPECTED.md says. missingFace.ascii.stl is the exception:
/// EXPECTED.md calls it "cut off inside a facet", but the file is three complete facets and an
/// `endsolid`, a tetrahedron with one face missing, which is a valid open mesh; it is accepted.
#[test]
fn broken_corpus_files_do_what_expected_md_says() {
    let Some(corpus) = common::corpus() else { return };
    let broken = corpus.join("broken");
    let reject = [
        "empty.stl",
        "incorrectFaceCounter.bin.stl",
        "twoVertices.ascii.stl",
        "IndexOutOfRange.gltf",
        "BoxWithInfinites.glb",
        "RecursiveNodes.gltf",
    ];
    let accept = [
        "fourVertices.ascii.stl",
        "quad.ascii.stl",
        "missingEndsolid.ascii.stl",
        "solidNameMismatch.ascii.stl",
        "missingNormal.ascii.stl",
        "wrongNormal.ascii.stl",
        "wrongNormals.ascii.stl",
        "notANumberNormal.ascii.stl",
        "wrongHeader.bin.stl",
        "singleFace.ascii.stl",
        "missingFace.ascii.stl",
    ];
    for name in reject {
        let err = load_file(&broken.join(name), &IngestLimits::default())
            .map(|_| ())
            .expect_err(name);
        assert!(!err.to_string().contains('\n'));
        println!("{name}: rejected: {err}");
    }
    for name in accept {
        let (mesh, stats) =
            load_file(&broken.join(name), &IngestLimits::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        println!(
            "{name}: accepted, {} triangles, {:?}",
            mesh.triangles.len(),
            stats.warnings
        );
        let cooked = occluder_cook::cook::cook(mesh, stats, 0.0, &common::defaults(), false).expect("cooks");
        if name == "singleFace.ascii.stl" {
            // One face encloses nothing: at most a patch on the face itself.
            assert!(cooked.occluder.solid.triangles.is_empty());
            assert!(cooked.occluder.panels.iter().all(|p| p.shape == Shape::Patches));
        }
    }
    assert!(matches!(
        load_file(&broken.join("BoxWithInfinites.glb"), &IngestLimits::default()),
        Err(IngestError::NonFinite(..))
    ));
}

#[test]
fn obj_lines_continued_with_a_backslash_and_crlf_are_joined() {
    let text = "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\nusemtl \r\nf 1 2 \\\r\n3 4\r\n";
    let (mesh, _) = load_bytes(text.as_bytes(), Format::Obj, None, &IngestLimits::default()).unwrap();
    assert_eq!(mesh.triangles.len(), 2);
}

/// gltf-json 1.4's validator indexes the accessor a primitive's POSITION names before checking
/// it (mesh.rs): a GLB with a few bytes changed there is refused in one line, never a panic.
#[test]
fn a_glb_whose_position_names_no_accessor_is_refused_in_one_line() {
    let cube = common::cuboid(Vec3::ZERO, Vec3::ONE, &[]);
    let part = glb::Part {
        name: "cube",
        mesh: &cube,
        double_sided: false,
    };
    let mut bytes = glb::write(&[part], serde_json::json!({}));
    let position = bytes
        .windows(12)
        .position(|w| w == b"\"POSITION\":0")
        .expect("the GLB names its positions");
    bytes[position + 11] = b'9';
    for read in [
        load_bytes(&bytes, Format::Gltf, None, &IngestLimits::default()).map(|_| ()),
        glb::read_parts(&bytes).map(|_| ()),
    ] {
        let error = read.expect_err("no accessor 9").to_string();
        assert!(error.starts_with("malformed glTF file"), "{error}");
        assert!(!error.contains('\n') && error.chars().count() <= 200, "{error}");
    }
}

/// A file that fails validation in a hundred places gets its first problem and how many more,
/// a required extension first: it is why the accessors have no data.
#[test]
fn a_draco_gltf_is_refused_in_one_short_line_naming_the_extension() {
    let Some(dir) = common::corpus() else { return };
    let error = load_file(
        &dir.join("formats/2cylinder-engine-draco.gltf"),
        &IngestLimits::default(),
    )
    .expect_err("draco is not decoded")
    .to_string();
    println!("{error}");
    assert!(
        error.chars().count() <= 200,
        "{} characters: {error}",
        error.chars().count()
    );
    assert!(
        error.contains("KHR_draco_mesh_compression") && error.contains("more problems"),
        "{error}"
    );
    assert!(
        error.contains("gltf-transform decompress"),
        "says how to convert it: {error}"
    );
}

/// A required extension that touches only textures (EXT_texture_webp here) blocks nothing: the
/// geometry reads, and the warnings name what was ignored. One that touches geometry still fails.
#[test]
fn a_required_texture_extension_does_not_block_the_geometry() {
    let Some(dir) = common::corpus() else { return };
    let (with_webp, stats) =
        load_file(&dir.join("formats/duck-webp-required.glb"), &IngestLimits::default()).expect("the geometry reads");
    let (plain, _) = load_file(&dir.join("duck.glb"), &IngestLimits::default()).expect("duck loads");
    // The same geometry is the same key: the cook gives the same occluder.
    let cook = common::defaults().cook;
    assert_eq!(
        occluder_cook::key::cache_key(&with_webp, &cook),
        occluder_cook::key::cache_key(&plain, &cook)
    );
    assert!(
        stats.warnings.iter().any(|w| w.contains("ignored EXT_texture_webp")),
        "{:?}",
        stats.warnings
    );
    assert!(
        load_file(
            &dir.join("formats/2cylinder-engine-draco.gltf"),
            &IngestLimits::default()
        )
        .is_err()
    );
}

/// Why a glTF document is refused, as the one-line message.
fn refusal(doc: &[u8], what: &str) -> String {
    let read = load_bytes(doc, Format::Gltf, None, &IngestLimits::default());
    read.map(|_| ()).expect_err(what).to_string()
}

/// A glTF whose one triangle lies under `nodes`, with `scene_nodes` listed in its scene.
fn gltf_with_nodes(nodes: serde_json::Value, scene_nodes: serde_json::Value) -> Vec<u8> {
    let positions: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let bin: Vec<u8> = positions.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
    let uri = format!("data:application/octet-stream;base64,{}", base64_encode(&bin));
    serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": scene_nodes}],
        "nodes": nodes,
        "buffers": [{"byteLength": 36, "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}, {"primitives": [{"attributes": {"POSITION": 0}}]}]
    })
    .to_string()
    .into_bytes()
}

/// 40 layers in which each node has two parents place 2^40 copies of one triangle: refused
/// from the counts, at once, with no copy made.
#[test]
fn a_gltf_node_graph_that_reuses_nodes_is_refused_before_expanding() {
    let layers = 40;
    let mut nodes: Vec<serde_json::Value> = (0..layers)
        .flat_map(|k| {
            let next = if k + 1 < layers {
                vec![2 * (k + 1), 2 * (k + 1) + 1]
            } else {
                vec![2 * layers]
            };
            [
                serde_json::json!({"children": next}),
                serde_json::json!({"children": next}),
            ]
        })
        .collect();
    nodes.push(serde_json::json!({"mesh": 0}));
    let bytes = gltf_with_nodes(nodes.into(), serde_json::json!([0, 1]));
    let start = std::time::Instant::now();
    let message = refusal(&bytes, "2^41 triangles");
    assert!(message.contains("over cook.max_placed_triangles"), "{message}");
    assert!(start.elapsed().as_secs_f64() < 1.0, "{:?}", start.elapsed());
    // Under a lower limit, a small reuse is refused too; within it, each copy is placed.
    let reused = gltf_with_nodes(
        serde_json::json!([{"children": [1, 1, 1]}, {"mesh": 0}]),
        serde_json::json!([0, 0]),
    );
    let tight = IngestLimits {
        max_placed_triangles: 5,
        ..IngestLimits::default()
    };
    assert!(load_bytes(&reused, Format::Gltf, None, &tight).is_err());
    let (_, stats) = load_bytes(&reused, Format::Gltf, None, &IngestLimits::default()).expect("6 copies");
    assert_eq!(stats.input_triangles, 6);
}

/// A chain of nodes deeper than any thread's stack reads without overflowing it.
#[test]
fn a_deep_gltf_node_chain_reads() {
    let depth = 200_000;
    let mut nodes: Vec<serde_json::Value> = (1..depth).map(|k| serde_json::json!({"children": [k]})).collect();
    nodes.push(serde_json::json!({"mesh": 0, "translation": [1.0, 0.0, 0.0]}));
    let bytes = gltf_with_nodes(nodes.into(), serde_json::json!([0]));
    let (mesh, _) = load_bytes(&bytes, Format::Gltf, None, &IngestLimits::default()).expect("reads");
    assert_eq!(mesh.bounds().0, Vec3::new(1.0, 0.0, 0.0));
}

/// A sparse accessor with no bufferView declares items that no byte backs: under 3 indices, a
/// count past the limit is refused before anything is allocated.
#[test]
fn a_sparse_accessor_without_bytes_is_bounded() {
    let mut doc: serde_json::Value = serde_json::from_slice(&gltf_with_nodes(
        serde_json::json!([{"mesh": 0}]),
        serde_json::json!([0]),
    ))
    .unwrap();
    doc["accessors"] = serde_json::json!([{
        "componentType": 5126, "count": 2_000_000_000u64, "type": "VEC3",
        "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0],
        "sparse": {"count": 1, "indices": {"bufferView": 0, "componentType": 5125},
                   "values": {"bufferView": 0}}
    }, {"bufferView": 0, "componentType": 5125, "count": 3, "type": "SCALAR"}]);
    doc["meshes"][0]["primitives"][0]["indices"] = 1.into();
    let start = std::time::Instant::now();
    let message = refusal(doc.to_string().as_bytes(), "2e9 items");
    assert!(message.contains("no bufferView backs"), "{message}");
    assert!(start.elapsed().as_secs_f64() < 1.0, "{:?}", start.elapsed());
}

/// A mesh that no node of the scene places is not read, as a part of a level either.
#[test]
fn meshes_no_node_places_are_left_out() {
    let bytes = gltf_with_nodes(serde_json::json!([{"mesh": 1}]), serde_json::json!([0]));
    let (parts, placements) =
        occluder_cook::mesh::load_instances(&bytes, Format::Gltf, None, &IngestLimits::default()).expect("reads");
    assert_eq!((parts.len(), placements.len()), (1, 1));
    assert_eq!(parts[0].0, "mesh 1");
}

#[test]
fn the_default_ingest_limits_are_the_configs() {
    assert_eq!(common::defaults().ingest_limits(), IngestLimits::default());
}

/// Found by the fuzzer: indices that name a float accessor made gltf's reader reach
/// `unreachable!`. Positions that are not float VEC3 are refused the same way.
#[test]
fn accessors_of_the_wrong_type_are_refused_not_panicked_on() {
    let base: serde_json::Value = serde_json::from_slice(&gltf_with_nodes(
        serde_json::json!([{"mesh": 0}]),
        serde_json::json!([0]),
    ))
    .unwrap();
    let mut float_indices = base.clone();
    float_indices["meshes"][0]["primitives"][0]["indices"] = 0.into();
    let mut integer_positions = base;
    integer_positions["accessors"][0]["componentType"] = 5123.into();
    for (what, doc, expected) in [
        ("float indices", float_indices, "not unsigned integer scalars"),
        ("integer positions", integer_positions, "not float VEC3"),
    ] {
        let message = refusal(doc.to_string().as_bytes(), what);
        assert!(message.contains(expected), "{what}: {message}");
    }
}

/// KHR_mesh_quantization: 16-bit normalized positions under a scale, and 8-bit unsigned ones as
/// they are, read where the extension is required.
#[test]
fn quantized_positions_are_read() {
    let mut bin = Vec::new();
    for p in [[0i16, 0, 0], [32767, 0, 0], [0, 32767, 0]] {
        bin.extend(p.iter().flat_map(|c| c.to_le_bytes()));
        bin.extend([0, 0]); // stride 8
    }
    for p in [[0u8, 0, 0], [4, 0, 0], [0, 4, 0]] {
        bin.extend(p);
        bin.push(0); // stride 4
    }
    let uri = format!("data:application/octet-stream;base64,{}", base64_encode(&bin));
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
        "extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"],
        "nodes": [{"mesh": 0, "scale": [2.0, 2.0, 2.0]}, {"mesh": 1, "translation": [10.0, 0.0, 0.0]}],
        "buffers": [{"byteLength": bin.len(), "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 24, "byteStride": 8}, {"buffer": 0, "byteOffset": 24, "byteLength": 12, "byteStride": 4}],
        "accessors": [
            {"bufferView": 0, "componentType": 5122, "normalized": true, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [32767.0, 32767.0, 0.0]},
            {"bufferView": 1, "componentType": 5121, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [4.0, 4.0, 0.0]}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}, {"primitives": [{"attributes": {"POSITION": 1}}]}]
    });
    let (mesh, _) = load_bytes(doc.to_string().as_bytes(), Format::Gltf, None, &IngestLimits::default())
        .expect("quantized positions read");
    assert_eq!(mesh.triangles.len(), 2);
    let mut corners: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    corners.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert_eq!(
        corners,
        [
            [0.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [2.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            [10.0, 4.0, 0.0],
            [14.0, 0.0, 0.0]
        ]
    );
    // Without the extension, integer positions are refused.
    let mut plain = doc;
    plain.as_object_mut().unwrap().remove("extensionsUsed");
    plain.as_object_mut().unwrap().remove("extensionsRequired");
    let message = refusal(plain.to_string().as_bytes(), "integers without the extension");
    assert!(message.contains("need KHR_mesh_quantization"), "{message}");
}

/// EXT_meshopt_compression: positions and triangle indices compressed by meshoptimizer, in a
/// buffer whose fallback has no bytes, read as the plain triangles.
#[test]
fn meshopt_compressed_views_are_decoded() {
    let cube = common::cuboid(Vec3::ZERO, Vec3::ONE, &[]);
    let positions: Vec<[f32; 3]> = cube.positions.iter().map(|p| p.to_array()).collect();
    let indices: Vec<u32> = cube.triangles.iter().flatten().copied().collect();
    let vertices = meshopt::encode_vertex_buffer(&positions).unwrap();
    let triangles = meshopt::encode_index_buffer(&indices, positions.len()).unwrap();
    let mut bin = vertices.clone();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let triangles_at = bin.len();
    bin.extend(&triangles);
    let uri = format!("data:application/octet-stream;base64,{}", base64_encode(&bin));
    let compressed = |offset: usize, length: usize, stride: usize, count: usize, mode: &str| {
        serde_json::json!({"EXT_meshopt_compression": {"buffer": 0, "byteOffset": offset, "byteLength": length,
            "byteStride": stride, "count": count, "mode": mode}})
    };
    let doc = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "extensionsUsed": ["EXT_meshopt_compression"], "extensionsRequired": ["EXT_meshopt_compression"],
        "buffers": [{"byteLength": bin.len(), "uri": uri},
                    {"byteLength": 96 + 144, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}],
        "bufferViews": [
            {"buffer": 1, "byteLength": 96, "byteStride": 12, "extensions": compressed(0, vertices.len(), 12, 8, "ATTRIBUTES")},
            {"buffer": 1, "byteOffset": 96, "byteLength": 144, "extensions": compressed(triangles_at, triangles.len(), 4, 36, "TRIANGLES")}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]},
            {"bufferView": 1, "componentType": 5125, "count": 36, "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    });
    let (mesh, stats) = load_bytes(doc.to_string().as_bytes(), Format::Gltf, None, &IngestLimits::default())
        .expect("the compressed views decode");
    assert_eq!((mesh.triangles.len(), stats.welded_vertices), (12, 8));
    assert!((common::signed_volume(&mesh) - 1.0).abs() < 1e-6);
    // A count the compressed bytes cannot hold is refused before decoding.
    let mut inflated = doc;
    inflated["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["count"] = 50_000_000.into();
    let message = refusal(inflated.to_string().as_bytes(), "inflated count");
    assert!(message.contains("more than the codec gives"), "{message}");
}

/// Meshes past the scale the cook's arithmetic holds are refused in one line: a vertex past
/// ±1e30 (f32 sums of such overflow) or a mesh under 1e-12 across. Those at the ends of the range
/// cook as the same mesh at scale 1 does.
#[test]
fn meshes_too_far_out_or_too_small_are_refused_and_the_ends_of_the_range_cook_alike() {
    let cube_obj = |size: f32, offset: f32| {
        let cube = common::cuboid(Vec3::splat(offset), Vec3::splat(offset + size), &[]);
        common::http::obj_text(&cube)
    };
    let read = |obj: Vec<u8>| load_bytes(&obj, Format::Obj, None, &IngestLimits::default());
    for (size, offset) in [(1e37, 2e38), (2e31, -1e31)] {
        let err = read(cube_obj(size, offset)).expect_err("refused");
        assert!(matches!(err, IngestError::FarVertex(..)), "{err}");
        assert!(err.to_string().contains("past ±1e30"), "{err}");
    }
    for size in [1e-13, 1e-16, 1e-40] {
        let err = read(cube_obj(size, 0.0)).expect_err("refused");
        assert!(matches!(err, IngestError::TooSmall(_)), "{err}");
        assert!(!err.to_string().contains('\n'));
    }
    let cook = |obj: Vec<u8>| {
        let (mesh, stats) = read(obj).expect("read");
        let cooked = occluder_cook::cook::cook(mesh, stats, 0.0, &common::defaults(), true).expect("cooks");
        let quality = cooked.report.quality.expect("evaluated");
        (cooked.report.occluder.triangles, quality.coverage, quality.false_pixels)
    };
    let unit = cook(cube_obj(1.0, 0.0));
    assert_eq!(unit.2, 0);
    for (size, offset) in [(2e29, -1e29), (1e-11, 0.0)] {
        assert_eq!(cook(cube_obj(size, offset)), unit, "a cube {size} across at {offset}");
    }
}
