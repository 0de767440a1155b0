//! Maps as one soup, and probe culling: a small map of two rooms joined by a doorway, built in
//! code, with the probe counts worked out by hand.

mod common;
use common::{cli, cuboid};
use glam::{DVec3, Vec3};
use occluder_cook::level::cull::probes::{Buffer, probe_eval};
use occluder_cook::level::free_space::{FreeSpace, Pose, Probe};
use occluder_cook::level::{Level, MeshRef};
use occluder_cook::mesh::Mesh;
use occluder_cook::occluder::BOX_FACES;
use occluder_cook::voxel::bricks::BrickGrid;

/// The solids of the map: a floor 20 × 10, outer walls 4 high, and a wall across the middle
/// (x 9 to 11) with a doorway from z 4 to 6: room A west of it, room B east.
fn blocks() -> Vec<(Vec3, Vec3)> {
    vec![
        (Vec3::new(0.0, -1.0, 0.0), Vec3::new(20.0, 0.0, 10.0)),
        (Vec3::new(-1.0, -1.0, -1.0), Vec3::new(0.0, 4.0, 11.0)),
        (Vec3::new(20.0, -1.0, -1.0), Vec3::new(21.0, 4.0, 11.0)),
        (Vec3::new(0.0, -1.0, -1.0), Vec3::new(20.0, 4.0, 0.0)),
        (Vec3::new(0.0, -1.0, 10.0), Vec3::new(20.0, 4.0, 11.0)),
        (Vec3::new(9.0, 0.0, 0.0), Vec3::new(11.0, 4.0, 4.0)),
        (Vec3::new(9.0, 0.0, 6.0), Vec3::new(11.0, 4.0, 10.0)),
    ]
}

fn map() -> Mesh {
    let mut map = Mesh::default();
    for (lo, hi) in blocks() {
        map.append(&cuboid(lo, hi, &[]));
    }
    map
}

/// A cuboid whose faces are each split into `n` × `n` quads, as exported maps are.
fn tessellated(lo: Vec3, hi: Vec3, n: usize) -> Mesh {
    let corner = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let mut mesh = Mesh::default();
    for q in BOX_FACES {
        let [a, b, c, d] = q.map(corner);
        let base = mesh.positions.len() as u32;
        for i in 0..=n {
            for j in 0..=n {
                let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                mesh.positions
                    .push((a * (1.0 - s) + b * s) * (1.0 - t) + (d * (1.0 - s) + c * s) * t);
            }
        }
        let at = |i: usize, j: usize| base + (i * (n + 1) + j) as u32;
        for i in 0..n {
            for j in 0..n {
                mesh.triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
    }
    mesh
}

fn probe(lo: [f64; 3], hi: [f64; 3]) -> Probe {
    Probe { lo, hi }
}

const BUFFER: Buffer = Buffer {
    width: 256,
    height: 128,
};
const TRUTH: Buffer = Buffer {
    width: 1024,
    height: 512,
};

#[test]
fn probe_counts_match_the_hand_count() {
    let map = map();
    // In room A, looking east at the middle wall.
    let camera = Pose {
        eye: DVec3::new(2.0, 1.7, 5.0),
        forward: DVec3::X,
    };
    let probes = [
        // 0: in room A, in front of the camera: seen.
        probe([5.0, 0.01, 4.5], [6.0, 1.0, 5.5]),
        // 1: in room B behind the wall's south half: hidden.
        probe([15.0, 0.01, 1.0], [16.0, 1.0, 2.0]),
        // 2: in room B, seen through the doorway.
        probe([15.0, 0.01, 4.6], [16.0, 1.0, 5.4]),
        // 3: behind the camera: out of view, counted nowhere.
        probe([0.5, 0.01, 4.5], [1.0, 1.0, 5.5]),
        // 4: in room B behind the wall's north half: hidden.
        probe([13.0, 0.01, 8.0], [14.0, 1.0, 9.0]),
    ];
    let with = |occluder: &Mesh| probe_eval(&map, occluder, &[camera], &probes, BUFFER, TRUTH);

    // The map itself culls both hidden probes: the limit, and the map as the occluder.
    let itself = with(&map);
    assert_eq!(itself.probes_in_view, 4);
    for counts in [itself.occluder, itself.limit] {
        assert_eq!(counts.probes_hidden, 2, "{counts:?}");
        assert_eq!(counts.probes_culled, 2, "{counts:?}");
        assert_eq!(counts.probes_wrongly_culled, 0, "{counts:?}");
    }

    // The wall's south half alone culls probe 1 only.
    let south = cuboid(Vec3::new(9.0, 0.0, 0.0), Vec3::new(11.0, 4.0, 4.0), &[]);
    let half = with(&south);
    assert_eq!((half.occluder.probes_hidden, half.occluder.probes_culled), (2, 1));
    assert_eq!(half.occluder.probes_wrongly_culled, 0);
    assert_eq!(half.limit, itself.limit, "the limit does not depend on the occluder");

    // A board in front of the camera that the map does not have hides everything ahead: the
    // two probes it hides that the map hides too are culled, the two in sight are wrongly so.
    let board = cuboid(Vec3::new(4.0, 0.0, 3.0), Vec3::new(4.2, 3.0, 7.0), &[]);
    let wrong = with(&board);
    assert_eq!(wrong.occluder.probes_culled, 2);
    assert_eq!(wrong.occluder.probes_wrongly_culled, 2);
}

#[test]
fn cameras_and_probes_stand_on_the_floors_inside_the_rooms() {
    let map = map();
    let grid = BrickGrid::voxelize(&map, 0.1, None).expect("small grid");
    let space = FreeSpace::new(&grid, 1.7);
    let cameras = space.cameras(40, 7);
    assert_eq!(cameras.len(), 40);
    let in_a_wall = |p: DVec3| {
        blocks()
            .iter()
            .any(|&(lo, hi)| p.cmpgt(lo.as_dvec3()).all() && p.cmplt(hi.as_dvec3()).all())
    };
    for c in &cameras {
        // On the floor at 0, not on a wall's top at 4 nor outside the outer walls.
        assert!(c.eye.y >= 1.7 && c.eye.y <= 1.7 + 0.2, "{c:?}");
        assert!(
            c.eye.x > 0.0 && c.eye.x < 20.0 && c.eye.z > 0.0 && c.eye.z < 10.0,
            "{c:?}"
        );
        assert!(!in_a_wall(c.eye), "{c:?}");
    }
    // Both rooms get cameras.
    assert!(cameras.iter().any(|c| c.eye.x < 9.0) && cameras.iter().any(|c| c.eye.x > 11.0));
    let probes = space.probes(100, 7);
    assert_eq!(probes.len(), 100);
    for p in &probes {
        let (lo, hi) = (DVec3::from_array(p.lo), DVec3::from_array(p.hi));
        assert!(lo.y >= 0.0 && lo.y <= 0.2, "{p:?} stands on the floor");
        let touches = blocks()
            .iter()
            .any(|&(b_lo, b_hi)| lo.cmplt(b_hi.as_dvec3()).all() && hi.cmpgt(b_lo.as_dvec3()).all());
        assert!(!touches, "{p:?} overlaps a wall");
        assert!(
            hi.y - lo.y >= 1.7 * 0.25 - 1e-9 && hi.y - lo.y <= 1.7 * 1.25 + 0.1,
            "{p:?}"
        );
    }
    // Too tall a player fits nowhere: nothing, rather than a camera in the wrong place.
    assert!(FreeSpace::new(&grid, 40.0).cameras(5, 7).is_empty());
}

#[test]
fn a_soup_cooks_to_few_triangles_that_cull_what_the_map_culls() {
    let mut map = Mesh::default();
    for (lo, hi) in blocks() {
        map.append(&tessellated(lo, hi, 6));
    }
    let dir = std::env::temp_dir().join(format!("occluder-cook-soup-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let store = occluder_cook::store::sled::SledStore::open(&dir, 1 << 24).expect("sled opens");
    let level = Level {
        name: "rooms".into(),
        instances: vec![(MeshRef::Part(0), glam::DMat4::IDENTITY)],
        parts: vec![("rooms".into(), map.clone(), Default::default())],
    };
    let settings = common::defaults();
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let bake = || {
        runtime.block_on(occluder_cook::level::soup::bake_soup(
            &level, &settings, &store, "a test",
        ))
    };
    let baked = bake().expect("the soup bakes");
    let report = &baked.report;
    let soup = report.soup.as_ref().expect("a soup's report");
    assert_eq!(soup.map_triangles, map.triangles.len());
    assert!(
        report.triangles_after * 10 <= map.triangles.len(),
        "{} of {}",
        report.triangles_after,
        map.triangles.len()
    );
    assert!(
        report.triangles_after > 0 && soup.grid.bricks > 0 && soup.eye_points > 0,
        "{soup:?}"
    );

    // The same bake again comes from the cache, byte for byte.
    let again = bake().expect("the soup bakes again");
    assert_eq!(again.report.cache_hits, 1);
    assert_eq!(again.glb, baked.glb);

    let occluder = occluder_cook::level::occluder_mesh(&baked.glb).expect("the GLB reads back");
    let grid = BrickGrid::voxelize(&map, 0.05, None).expect("small grid");
    let space = FreeSpace::new(&grid, 1.7);
    let (cameras, probes) = (space.cameras(30, 1), space.probes(200, 2));
    let r = probe_eval(&map, &occluder, &cameras, &probes, BUFFER, TRUTH);
    assert_eq!(r.occluder.probes_wrongly_culled, 0, "{r:?}");
    assert_eq!(r.limit.probes_wrongly_culled, 0, "{r:?}");
    assert!(r.limit.probes_culled > 100, "the walls hide many probes: {r:?}");
    assert!(r.occluder.probes_culled * 10 >= r.limit.probes_culled * 8, "{r:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cull_eval_reports_probes_from_the_command_line() {
    let dir = std::env::temp_dir().join(format!("occluder-cook-probes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let map_path = dir.join("rooms.obj");
    std::fs::write(&map_path, common::http::obj_text(&map())).expect("write map");
    let (glb, json) = (dir.join("rooms.glb"), dir.join("probes.json"));
    let data = dir.join("data");
    let (code, out, err) = cli(&[
        "level",
        map_path.to_str().unwrap(),
        "--soup",
        "-o",
        glb.to_str().unwrap(),
        "--data-dir",
        data.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.contains("cooked as one soup: asked for (--soup)"), "{out}");
    let (code, out, err) = cli(&[
        "cull-eval",
        map_path.to_str().unwrap(),
        glb.to_str().unwrap(),
        "--probes",
        "100",
        "--cameras",
        "10",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json written")).expect("json");
    for counts in [&report, &report["limit"]] {
        for key in ["probes_hidden", "probes_culled", "probes_wrongly_culled"] {
            assert!(counts[key].is_u64(), "{key} missing: {report}");
        }
        assert_eq!(counts["probes_wrongly_culled"], 0, "{report}");
    }
    assert!(report["limit"]["probes_culled"].as_u64() > Some(0), "{report}");
    assert!(report["grid"]["bricks"].as_u64() > Some(0), "{report}");

    // Bad settings: one line each, and no panic.
    for (flag, value, says) in [
        ("--buffer", "300x500", "height"),
        ("--eye-height", "40", "room for"),
        ("--probes", "0", "--probes"),
    ] {
        let mut args = vec![
            "cull-eval",
            map_path.to_str().unwrap(),
            glb.to_str().unwrap(),
            flag,
            value,
        ];
        if flag != "--probes" {
            args.extend(["--probes", "10"]);
        }
        let (code, out, err) = cli(&args);
        assert_ne!(code, 0, "{flag} {value}: {out}");
        assert!(err.contains(says), "{flag} {value}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
