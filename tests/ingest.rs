//! Ingest: each format from bytes built here, the lenient readings, and the rejections.

mod common;
use common::cuboid;
use glam::Vec3;
use occluder_cook::mesh::{Format, IngestError, glb, load_bytes, load_file};
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
    let (from_obj, stats) = load_bytes(obj_cube().as_bytes(), Format::Obj, None).unwrap();
    assert_eq!((from_obj.triangles.len(), stats.welded_vertices), (12, 8));
    let part = glb::Part {
        name: "cube",
        mesh: &from_obj,
        double_sided: false,
    };
    let glb_bytes = glb::write(&[part], serde_json::json!({}));
    let (from_glb, _) = load_bytes(&glb_bytes, Format::Gltf, None).unwrap();
    assert_eq!(from_glb.triangles, from_obj.triangles);
    let soup: Vec<[Vec3; 3]> = (0..12).map(|t| from_obj.corners(t)).collect();
    // A binary header that starts with "solid" is still binary: the size says so.
    let (from_stl, stats) = load_bytes(&binary_stl(&soup, b"solid but binary"), Format::Stl, None).unwrap();
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
    let (mesh, stats) = load_bytes(doc.to_string().as_bytes(), Format::Gltf, None).unwrap();
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
        let err = load_bytes(&bytes, format, None).expect_err(what).to_string();
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
    match load_bytes(doc.to_string().as_bytes(), Format::Gltf, None) {
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
        let err = load_file(&broken.join(name)).map(|_| ()).expect_err(name);
        assert!(!err.to_string().contains('\n'));
        println!("{name}: rejected: {err}");
    }
    for name in accept {
        let (mesh, stats) = load_file(&broken.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
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
        load_file(&broken.join("BoxWithInfinites.glb")),
        Err(IngestError::NonFinite(..))
    ));
}

#[test]
fn obj_lines_continued_with_a_backslash_and_crlf_are_joined() {
    let text = "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\nusemtl \r\nf 1 2 \\\r\n3 4\r\n";
    let (mesh, _) = load_bytes(text.as_bytes(), Format::Obj, None).unwrap();
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
        load_bytes(&bytes, Format::Gltf, None).map(|_| ()),
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
    let error = load_file(&dir.join("formats/2cylinder-engine-draco.gltf"))
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
    let (with_webp, stats) = load_file(&dir.join("formats/duck-webp-required.glb")).expect("the geometry reads");
    let (plain, _) = load_file(&dir.join("duck.glb")).expect("duck loads");
    assert_eq!(with_webp.triangles.len(), plain.triangles.len());
    assert!(
        stats.warnings.iter().any(|w| w.contains("ignored EXT_texture_webp")),
        "{:?}",
        stats.warnings
    );
    assert!(load_file(&dir.join("formats/2cylinder-engine-draco.gltf")).is_err());
}
