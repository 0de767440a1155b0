//! PLY and FBX ingest: files built here in each encoding, the frame conversion, mirrored nodes,
//! and the refusals; the corpus's FBX pivots placed where the file's transforms say.

mod common;
use common::{FBX_MIRRORED_CUBE, cuboid, signed_volume};
use glam::{DMat4, DVec3, Vec3};
use occluder_cook::mesh::{Format, IngestError, IngestLimits, Mesh, load_bytes, load_instances};

/// A unit cube as PLY: `encoding` is `ascii`, `binary_little_endian` or `binary_big_endian`.
/// Faces are quads, and each vertex carries a normal and a colour, which must be ignored.
fn ply_cube(encoding: &str) -> Vec<u8> {
    let cube = cuboid(Vec3::ZERO, Vec3::ONE, &[]);
    let quads: Vec<[u32; 4]> = occluder_cook::occluder::BOX_FACES
        .iter()
        .map(|q| q.map(|i| i as u32))
        .collect();
    let mut out = format!(
        "ply\nformat {encoding} 1.0\ncomment made by a test\nelement vertex 8\nproperty float x\n\
         property float y\nproperty float z\nproperty float nx\nproperty uchar red\n\
         element face 6\nproperty list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    let big = encoding == "binary_big_endian";
    let f32_bytes = |v: f32| if big { v.to_be_bytes() } else { v.to_le_bytes() };
    let i32_bytes = |v: i32| if big { v.to_be_bytes() } else { v.to_le_bytes() };
    for p in &cube.positions {
        if encoding == "ascii" {
            out.extend(format!("{} {} {} 0.5 255\n", p.x, p.y, p.z).bytes());
        } else {
            for c in [p.x, p.y, p.z, 0.5] {
                out.extend(f32_bytes(c));
            }
            out.push(255);
        }
    }
    for q in &quads {
        if encoding == "ascii" {
            out.extend(format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]).bytes());
        } else {
            out.push(4);
            for &i in q {
                out.extend(i32_bytes(i as i32));
            }
        }
    }
    out
}

fn sorted_triangles(mesh: &Mesh) -> Vec<[[i64; 3]; 3]> {
    let mut triangles: Vec<_> = (0..mesh.triangles.len())
        .map(|t| mesh.corners(t).map(|p| p.to_array().map(|c| (c * 1e4).round() as i64)))
        .collect();
    triangles.sort();
    triangles
}

#[test]
fn ply_in_every_encoding_gives_the_cube_with_quads_fanned() {
    let reference = sorted_triangles(&cuboid(Vec3::ZERO, Vec3::ONE, &[]));
    for encoding in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let (mesh, stats) = load_bytes(&ply_cube(encoding), Format::Ply, None, &IngestLimits::default())
            .unwrap_or_else(|e| panic!("{encoding}: {e}"));
        assert_eq!((mesh.triangles.len(), stats.welded_vertices), (12, 8), "{encoding}");
        assert_eq!(
            sorted_triangles(&mesh),
            reference,
            "{encoding}: same triangles, same winding"
        );
    }
    // 12 triangles: one more than placing allows, 1,920 bytes to read where 1,000 are.
    let tight = IngestLimits {
        max_placed_triangles: 11,
        ..IngestLimits::default()
    };
    let small = IngestLimits {
        max_parse_bytes: 1000,
        ..IngestLimits::default()
    };
    for (limits, expected) in [
        (tight, "over cook.max_placed_triangles"),
        (small, "over service.max_parse_bytes"),
    ] {
        let refused = load_bytes(&ply_cube("ascii"), Format::Ply, None, &limits).map(|_| ());
        let message = refused.expect_err(expected).to_string();
        assert!(message.contains(expected), "{message}");
    }
}

#[test]
fn ply_refusals_are_one_line_and_allocate_nothing_declared() {
    let ascii = String::from_utf8(ply_cube("ascii")).unwrap();
    let binary = ply_cube("binary_little_endian");
    let inflated = {
        let mut b = binary.clone();
        let at = b.windows(16).position(|w| w == b"element vertex 8").unwrap();
        b.splice(at..at + 16, b"element vertex 4000000000".iter().copied());
        b
    };
    let cases: [(&str, Vec<u8>, &str); 5] = [
        ("a count the payload cannot hold", inflated, "declares at least"),
        (
            "a face index past the vertices",
            ascii.replace("4 0 ", "4 9 ").into_bytes(),
            "out of range",
        ),
        (
            "a negative face index",
            ascii.replace("4 0 ", "4 -1 ").into_bytes(),
            "out of range",
        ),
        (
            "no end_header",
            b"ply\nformat ascii 1.0\nelement vertex 1\n".to_vec(),
            "end_header",
        ),
        (
            "an element without properties",
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n\
              property float z\nelement junk 99999999999\nend_header\n"
                .to_vec(),
            "no properties",
        ),
    ];
    for (what, bytes, expected) in cases {
        let message = load_bytes(&bytes, Format::Ply, None, &IngestLimits::default())
            .map(|_| ())
            .expect_err(what)
            .to_string();
        assert!(message.contains(expected), "{what}: {message}");
        assert!(!message.contains('\n') && message.len() <= 200, "{what}: {message}");
    }
}

#[test]
fn fbx_mirrored_node_is_placed_in_y_up_metres_facing_outwards() {
    let (mesh, stats) = load_bytes(
        FBX_MIRRORED_CUBE.as_bytes(),
        Format::Fbx,
        None,
        &IngestLimits::default(),
    )
    .expect("reads");
    assert_eq!(mesh.triangles.len(), 12);
    // x mirrored then moved: [9, 10]; Z-up to Y-up takes (x, y, z) to (x, z, -y).
    let (lo, hi) = mesh.bounds();
    assert!(lo.abs_diff_eq(Vec3::new(9.0, 0.0, -1.0), 1e-6), "{lo}");
    assert!(hi.abs_diff_eq(Vec3::new(10.0, 1.0, 0.0), 1e-6), "{hi}");
    assert!(
        (signed_volume(&mesh) - 1.0).abs() < 1e-6,
        "outward: {}",
        signed_volume(&mesh)
    );
    let frame = stats.source_frame.expect("the report says where it came from");
    assert_eq!((frame.unit_meters, frame.up_axis), (1.0, "+Z"));
}

#[test]
fn fbx_refusals_are_one_line() {
    let truncated = &FBX_MIRRORED_CUBE.as_bytes()[..FBX_MIRRORED_CUBE.len() / 2];
    let bad_index = FBX_MIRRORED_CUBE.replace("0,3,2,-2,", "0,3,2,-99,");
    for (what, bytes) in [
        ("empty", &b""[..]),
        ("not FBX", &b"Kaydara FBX Binary  \0\x1a\0garbage"[..]),
        ("truncated", truncated),
        ("an index past the vertices", bad_index.as_bytes()),
    ] {
        match load_bytes(bytes, Format::Fbx, None, &IngestLimits::default()) {
            Err(e) => {
                let message = e.to_string();
                assert!(!message.contains('\n') && message.len() <= 200, "{what}: {message}");
            }
            // ufbx reads what it can of a damaged file; what it gives must still be a mesh.
            Ok((mesh, _)) => assert!(!mesh.triangles.is_empty(), "{what}"),
        }
    }
    assert!(matches!(
        load_bytes(b"", Format::Fbx, None, &IngestLimits::default()),
        Err(IngestError::Malformed { format: "FBX", .. })
    ));
}

/// An FBX node's local matrix without rotation: translation, then scaling about its pivot after
/// the scaling offset (the FBX SDK's T · Soff · Sp · S · Sp⁻¹).
fn fbx_local(t: [f64; 3], scaling_offset: [f64; 3], scaling_pivot: [f64; 3], s: [f64; 3]) -> DMat4 {
    let pivot = DVec3::from(scaling_pivot);
    DMat4::from_translation(DVec3::from(t))
        * DMat4::from_translation(DVec3::from(scaling_offset))
        * DMat4::from_translation(pivot)
        * DMat4::from_scale(DVec3::from(s))
        * DMat4::from_translation(-pivot)
}

#[test]
fn fbx_pivots_and_mirroring_place_every_cube() {
    let Some(dir) = common::corpus() else { return };
    let bytes = std::fs::read(dir.join("formats/cubes-mirroring-pivot.fbx")).expect("reads");
    let (parts, placements) = load_instances(&bytes, Format::Fbx, None, &IngestLimits::default()).expect("loads");
    // The file's values (metres, Y up, so no conversion): Cube2 is mirrored in y and parents a
    // Cube1; Cube3 parents another Cube1 with a scaling pivot and offset.
    let zero = [0.0; 3];
    let cube2 = fbx_local(
        [-0.0104023897647858, 0.00998288810253143, -0.0104375958442688],
        zero,
        zero,
        [0.1, -0.1, 0.1],
    );
    let cube3 = fbx_local(
        [-0.0106711769104004, 0.00998288810253143, 0.0939023494720459],
        zero,
        zero,
        [0.1; 3],
    );
    let child_of_2 = cube2
        * fbx_local(
            [1.04023897647858, -0.998288810253143, 1.04375958442688],
            zero,
            zero,
            [1.0; 3],
        );
    let child_of_3 = cube3
        * fbx_local(
            [1.04023897647858, -0.998288810253143, 1.18067407608032],
            [0.168946330316482, -0.207450555573549, 0.260819301999204],
            [-0.747048924260949, 0.917307372632704, -1.15329394027084],
            [0.77384837213491; 3],
        );
    let expected = [
        ("Cube2", cube2),
        ("Cube1", child_of_2),
        ("Cube3", cube3),
        ("Cube1", child_of_3),
    ];
    assert_eq!(placements.len(), expected.len());
    let mut outward_volume = 0.0;
    for (name, want) in expected {
        let found = placements
            .iter()
            .find(|(part, world)| parts[*part].0 == name && world.abs_diff_eq(want, 1e-6));
        let (part, world) = found.unwrap_or_else(|| panic!("{name} at {want:?}; placements {placements:?}"));
        let local = &parts[*part].1;
        let corners = local.positions.iter().map(|p| world.transform_point3(p.as_dvec3()));
        let (lo, hi) = occluder_cook::mesh::point_bounds(corners);
        println!("{name}: world bounds {lo} to {hi}");
        assert!(signed_volume(local) > 0.0, "{name} is authored facing outwards");
        outward_volume += signed_volume(local) * glam::DMat3::from_mat4(*world).determinant().abs();
    }
    // Read as one mesh, every cube faces outwards, the two mirrored ones too: the volumes add up.
    let (mesh, _) = load_bytes(&bytes, Format::Fbx, None, &IngestLimits::default()).expect("loads");
    let volume = signed_volume(&mesh);
    assert!(
        (volume - outward_volume).abs() < 1e-6 * outward_volume.max(1.0),
        "{volume} vs {outward_volume}"
    );
}

/// FBX array lengths are declared: an ASCII count is only a hint, and a binary array that
/// claims 2^31 doubles runs into ufbx's memory limit, not into the machine's memory.
#[test]
fn fbx_declared_array_lengths_allocate_nothing_unchecked() {
    let hinted = FBX_MIRRORED_CUBE.replace("Vertices: *24", "Vertices: *2000000000");
    let (mesh, _) = load_bytes(hinted.as_bytes(), Format::Fbx, None, &IngestLimits::default()).expect("a hint only");
    assert_eq!(mesh.triangles.len(), 12);
    let Some(dir) = common::corpus() else { return };
    let mut spider = std::fs::read(dir.join("formats/spider.fbx")).unwrap();
    // A binary array: its name, then its type ('d'), then its u32 length.
    let name = spider
        .windows(8)
        .position(|w| w == b"Vertices")
        .expect("spider has vertices");
    assert_eq!(spider[name + 8], b'd');
    spider[name + 9..name + 13].copy_from_slice(&0x7fff_ffffu32.to_le_bytes());
    let message = load_bytes(&spider, Format::Fbx, None, &IngestLimits::default())
        .map(|_| ())
        .expect_err("2^31 doubles")
        .to_string();
    assert!(message.contains("Memory limit"), "{message}");
}

/// FBX 6.1 (ASCII, `Properties60`, no global settings): read in the FBX defaults, centimetres,
/// so a unit cube moved 5 along x lies 5 to 6 cm out, in metres.
#[test]
fn fbx_6_is_read_in_its_default_unit() {
    let fbx6 = r#"; FBX 6.1.0 project file
FBXHeaderExtension:  {
	FBXHeaderVersion: 1003
	FBXVersion: 6100
}
Objects:  {
	Model: "Model::cube", "Mesh" {
		Version: 232
		Properties60:  {
			Property: "Lcl Translation", "Lcl Translation", "A+",5,0,0
		}
		Vertices: 0,0,0,1,0,0,1,1,0,0,1,0,0,0,1,1,0,1,1,1,1,0,1,1
		PolygonVertexIndex: 0,3,2,-2,4,5,6,-8,0,1,5,-5,1,2,6,-6,2,3,7,-7,3,0,4,-8
	}
}
Connections:  {
	Connect: "OO", "Model::cube", "Model::Scene"
}
"#;
    let (mesh, stats) = load_bytes(fbx6.as_bytes(), Format::Fbx, None, &IngestLimits::default()).expect("FBX 6 reads");
    assert_eq!(mesh.triangles.len(), 12);
    let (lo, hi) = mesh.bounds();
    assert!(
        lo.abs_diff_eq(Vec3::new(0.05, 0.0, 0.0), 1e-6) && hi.abs_diff_eq(Vec3::new(0.06, 0.01, 0.01), 1e-6),
        "{lo} {hi}"
    );
    assert!(
        (signed_volume(&mesh) - 1e-6).abs() < 1e-9,
        "outward: {}",
        signed_volume(&mesh)
    );
    assert_eq!(stats.source_frame.expect("the frame").unit_meters, 0.01);
}
