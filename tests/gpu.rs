//! The GPU stages against their CPU twins: surface and parity voxels identical, winding
//! within 0.1%. Runs on lavapipe where there is no hardware GPU; CI installs it, so there a
//! missing adapter fails instead of skipping.

mod common;
use common::{concat, cuboid, torus};
use glam::{IVec3, Vec3};
use occluder_cook::geom::camera::View;
use occluder_cook::geom::raster::depth_image;
use occluder_cook::gpu::{self, Gpu, GpuError};
use occluder_cook::mesh::{IngestLimits, Mesh, load_file, topology::orient_closed_components};
use occluder_cook::occluder::exposure::OpenViews;
use occluder_cook::voxel::bricks::BrickGrid;
use occluder_cook::voxel::winding::WindingField;
use occluder_cook::voxel::{Grid, InsideMethod, classify, surface};

fn differ(a: &[bool], b: &[bool]) -> usize {
    a.iter().zip(b).filter(|(x, y)| x != y).count()
}

/// Compares every stage on one mesh at one resolution; returns the winding differences.
fn compare(gpu: &Gpu, name: &str, mut mesh: Mesh, resolution: usize) -> usize {
    let topology = orient_closed_components(&mut mesh);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, resolution);
    let on_gpu = |method| common::solid(method, &mesh, &topology, &grid, Some(gpu));
    let on_cpu = |method| common::solid(method, &mesh, &topology, &grid, None);

    let (g, c) = (
        surface::gpu::voxelize(gpu, &mesh, &grid).expect("GPU surface"),
        surface::voxelize(&mesh, &grid),
    );
    assert_eq!(differ(&g, &c), 0, "{name} @{resolution}: surface voxels differ");
    assert!(c.iter().any(|&v| v), "{name}: no surface voxels");

    let (g, c) = (on_gpu(InsideMethod::Parity), on_cpu(InsideMethod::Parity));
    assert_eq!(differ(&g, &c), 0, "{name} @{resolution}: parity voxels differ");

    let (g, c) = (on_gpu(InsideMethod::Winding), on_cpu(InsideMethod::Winding));
    let d = differ(&g, &c);
    let share = d as f64 / grid.len() as f64;
    eprintln!(
        "{name} @{resolution}: {} voxels, {} inside; winding differs at {d} ({:.4}%)",
        grid.len(),
        c.iter().filter(|&&v| v).count(),
        share * 100.0
    );
    assert!(
        share <= 0.001,
        "{name} @{resolution}: winding differs at {d} voxels ({share:.5})"
    );
    if topology.boundary.is_empty() {
        assert_eq!(d, 0, "{name}: a closed mesh's winding is its crossing count, exactly");
    }
    d
}

#[test]
fn gpu_stages_match_their_cpu_twins_on_synthetic_shapes() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let shapes = [
        ("torus", torus(1.0, 0.4, 32, 16)),
        ("open box", cuboid(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 1.0), &[3])),
        (
            "two overlapping boxes",
            concat(&[
                cuboid(Vec3::ZERO, Vec3::splat(2.0), &[]),
                cuboid(Vec3::splat(1.0), Vec3::splat(3.0), &[]),
            ]),
        ),
        (
            "box missing two faces",
            cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), &[1, 3]),
        ),
    ];
    for (name, mesh) in shapes {
        for resolution in [17, 64] {
            compare(&gpu, name, mesh.clone(), resolution);
        }
    }
}

#[test]
fn winding_reads_open_edges_past_its_uniform_buffer_from_storage() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    // 1100 small separate triangles below a box open at +z: their 3300 open edges come first
    // and fill the 2048 the shader holds in its uniform buffer, so the box's own open edges,
    // without which none of its voxels counts as inside, are read from storage.
    let mut mesh = Mesh::default();
    for i in 0..1100u32 {
        let o = Vec3::new((i % 40) as f32 * 0.1 - 2.0, -3.0, (i / 40) as f32 * 0.1 - 2.0);
        mesh.positions.extend([o, o + Vec3::X * 0.02, o + Vec3::Z * 0.02]);
        mesh.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let mesh = concat(&[mesh, cuboid(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 1.0), &[5])]);
    let edges = orient_closed_components(&mut mesh.clone()).boundary.len();
    assert!(edges > 3300, "{edges} open edges");
    for resolution in [17, 32] {
        compare(&gpu, "open box over 1100 triangles", mesh.clone(), resolution);
    }
}

#[test]
fn gpu_stages_match_their_cpu_twins_on_corpus_meshes() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let Some(dir) = common::corpus() else { return };
    let mut largest = (0, String::new());
    for name in [
        "bunny-holes.obj",
        "spot.obj",
        "sphere-with-hole.stl",
        "soup.stl",
        "kenney-building-small-a.glb",
    ] {
        let (mesh, _) = load_file(&dir.join(name), &IngestLimits::default()).expect("corpus mesh loads");
        for resolution in [64, 128] {
            let d = compare(&gpu, name, mesh.clone(), resolution);
            if d > largest.0 {
                largest = (d, format!("{name} @{resolution}"));
            }
        }
    }
    eprintln!("largest winding difference: {} voxels ({})", largest.0, largest.1);
}

#[test]
fn a_triangle_spanning_the_grid_is_split_under_the_drivers_loop_limit() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    // llvmpipe stops an invocation's loops after 65535 iterations: this triangle's bounds hold
    // 4 million voxels, so it only comes out whole if the host splits it into work items.
    let mesh = Mesh {
        positions: vec![Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::ONE],
        triangles: vec![[0, 1, 2]],
    };
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 160);
    let (g, c) = (
        surface::gpu::voxelize(&gpu, &mesh, &grid).expect("GPU surface"),
        surface::voxelize(&mesh, &grid),
    );
    assert!(c.iter().filter(|&&v| v).count() > 30_000);
    assert_eq!(differ(&g, &c), 0);
}

#[test]
fn a_mesh_with_too_many_open_edges_for_one_thread_classifies_on_the_cpu_and_says_so() {
    if gpu::device_for_tests().is_none() {
        return;
    }
    // 2000 separate triangles: 6000 boundary edges.
    let mut mesh = Mesh::default();
    for i in 0..2000u32 {
        let o = Vec3::new((i % 50) as f32, (i / 50) as f32, (i % 7) as f32 * 0.1);
        mesh.positions.extend([o, o + Vec3::X * 0.8, o + Vec3::Y * 0.8]);
        mesh.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let settings = occluder_cook::config::load(
        None,
        &[
            ("cook.device".into(), toml::Value::String("gpu".into())),
            ("cook.resolution".into(), toml::Value::Integer(24)),
        ],
    )
    .unwrap();
    let cooked = occluder_cook::cook::cook(mesh, Default::default(), 0.0, &settings, false).expect("cooks");
    let r = &cooked.report;
    assert!(
        r.gpu_stages.contains(&"surface") && !r.gpu_stages.contains(&"inside"),
        "{:?}",
        r.gpu_stages
    );
    assert!(
        r.notes.iter().any(|n| n.contains("inside ran on the CPU")),
        "{:?}",
        r.notes
    );
}

#[test]
fn grids_larger_than_a_binding_are_done_in_slabs() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    // 64 KiB bindings: a 96³ grid of i32 sums needs many slabs, and the triangles several chunks.
    let small = gpu.with_max_binding(64 * 1024);
    let mut mesh = torus(1.0, 0.4, 96, 48);
    let topology = orient_closed_components(&mut mesh);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 96);
    assert!(grid.len() as u64 * 4 > 8 * small.max_binding && mesh.triangles.len() as u64 * 36 > small.max_binding);
    for method in [InsideMethod::Parity, InsideMethod::Winding] {
        let sliced = common::solid(method, &mesh, &topology, &grid, Some(&small));
        let whole = common::solid(method, &mesh, &topology, &grid, Some(&gpu));
        assert_eq!(sliced, whole, "{method:?}");
    }
    let sliced = surface::gpu::voxelize(&small, &mesh, &grid).expect("slabs run");
    assert_eq!(sliced, surface::voxelize(&mesh, &grid));
}

/// Runs the binary on one thread (so that `auto` sizes grids against one) with the Vulkan
/// loader pointed at no driver at all.
fn cook_without_adapter(args: &[&str]) -> (i32, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_occluder-cook"))
        .args(args)
        .env("RAYON_NUM_THREADS", "1")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .expect("the binary runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn device_gpu_without_an_adapter_fails_clearly_and_auto_falls_back_to_the_cpu() {
    let dir = std::env::temp_dir().join(format!("occluder-cook-noadapter-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (closed, open) = (dir.join("box.obj"), dir.join("open-box.obj"));
    std::fs::write(&closed, common::http::obj_text(&cuboid(Vec3::ZERO, Vec3::ONE, &[]))).unwrap();
    std::fs::write(&open, common::http::obj_text(&cuboid(Vec3::ZERO, Vec3::ONE, &[3]))).unwrap();
    let (closed, open) = (closed.to_str().unwrap(), open.to_str().unwrap());
    let (out, report) = (dir.join("o.glb"), dir.join("r.json"));
    let (out, report) = (out.to_str().unwrap(), report.to_str().unwrap());

    let (code, stderr) = cook_without_adapter(&["cook", closed, "-o", out, "--device", "gpu"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("no GPU adapter"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");

    // Boxes only: the box's own faces would cover it without the voxel stages, and no device.
    let cook = |mesh: &str, resolution: &str| {
        let boxes = r#"cook.shapes=["boxes"]"#;
        let args = [
            "cook",
            mesh,
            "-o",
            out,
            "--report",
            report,
            "--resolution",
            resolution,
            "--set",
            boxes,
        ];
        let (code, stderr) = cook_without_adapter(&args);
        assert_eq!(code, 0, "{stderr}");
        let report: serde_json::Value = serde_json::from_slice(&std::fs::read(report).unwrap()).unwrap();
        assert_eq!(report["device"], "cpu");
        report
    };
    // A grid too small to pay for opening a GPU stays on the CPU without looking for one.
    let report = cook(closed, "64");
    let notes = report["notes"].to_string();
    assert!(
        notes.contains("device=auto ran this cook on the CPU") && !notes.contains("adapter"),
        "{notes}"
    );
    assert!(report["occluder"]["triangles"].as_u64().unwrap() > 0);
    // An open mesh's grid of 96³ voxels would pay on one thread: auto looks, finds none, and says so.
    let notes = cook(open, "96")["notes"].to_string();
    assert!(notes.contains("found no GPU adapter"), "{notes}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn gpu_depth_images_match_the_cpu_rasterizer() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let mut meshes = vec![("torus".to_string(), torus(1.0, 0.4, 48, 24))];
    if let Some(dir) = common::corpus() {
        for name in ["bunny-holes.obj", "kenney-building-small-a.glb"] {
            meshes.push((
                name.into(),
                load_file(&dir.join(name), &IngestLimits::default())
                    .expect("corpus mesh loads")
                    .0,
            ));
        }
    }
    for (name, mesh) in meshes {
        let (center, radius) = mesh.bounding_sphere();
        let views: Vec<View> = occluder_cook::geom::camera::fibonacci_sphere(12)
            .into_iter()
            .map(|d| View::new(d, center, radius, 256))
            .collect();
        let images = occluder_cook::geom::raster::gpu::depth_images(&gpu, &mesh, &views).expect("GPU depth images");
        let tolerance = 2e-4 * radius as f32;
        let (mut covered, mut differ) = (0, 0);
        for (view, image) in views.iter().zip(&images) {
            let twin = depth_image(view, &mesh);
            for (&g, &c) in image.iter().zip(&twin) {
                covered += usize::from(c.is_finite());
                let same = (g.is_infinite() && c.is_infinite()) || (g - c).abs() <= tolerance;
                differ += usize::from(!same);
            }
        }
        eprintln!(
            "{name}: {covered} covered pixels; {differ} differ in coverage or by more than {tolerance:.1e} in depth"
        );
        // A mesh or image larger than one binding is left to the caller's CPU stage.
        let tiny = gpu.with_max_binding(16);
        let refused = occluder_cook::geom::raster::depth_images(&views[..2], &mesh, Some(&tiny));
        assert!(matches!(refused, Err(GpuError::Unsupported(_))), "{refused:?}");
        // The shader makes the twin's sums in f32 rather than f64: only exact ties may differ.
        assert!(
            differ as f64 <= 1e-5 * covered as f64,
            "{name}: {differ} of {covered} pixels differ"
        );
    }
}

/// Cooks on `device` without surface pieces, which have no GPU twin and would cover the open box
/// and the Kenney building alone, so that the voxel stages run.
fn cook_on(device: &str, mesh: Mesh) -> occluder_cook::cook::Cooked {
    let mut settings =
        occluder_cook::config::load(None, &[("cook.device".into(), toml::Value::String(device.into()))]).unwrap();
    settings.cook.shapes = common::VOXEL_AND_PANEL_SHAPES.to_vec();
    occluder_cook::cook::cook(mesh, Default::default(), 0.0, &settings, true).expect("cooks")
}

#[test]
fn a_cook_on_the_gpu_gives_the_cpu_occluder_with_no_false_pixels() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let timestamps = gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
    for (name, mesh) in [
        ("torus", torus(1.0, 0.45, 48, 24)),
        ("open box", cuboid(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 1.0), &[3])),
    ] {
        let (g, c) = (cook_on("gpu", mesh.clone()), cook_on("cpu", mesh));
        assert!(g.report.gpu_stages.contains(&"surface") && c.report.gpu_stages.is_empty());
        assert!(g.report.gpu_stages.contains(&"eval"), "{:?}", g.report.gpu_stages);
        // The device's own time per stage, where its passes can be timed; none on the CPU.
        let device_ms = &g.report.device_timings_ms;
        eprintln!("{name}: device ms {device_ms:?}");
        assert_eq!(
            device_ms.get("surface") > 0.0 && device_ms.get("inside") > 0.0,
            timestamps,
            "{name}"
        );
        assert!(c.report.device_timings_ms.is_empty());
        assert_eq!(g.occluder.solid.positions, c.occluder.solid.positions, "{name}");
        assert_eq!(g.report.occluder.triangles, c.report.occluder.triangles, "{name}");
        let (q, twin) = (g.report.quality.as_ref().unwrap(), c.report.quality.as_ref().unwrap());
        assert_eq!((q.false_pixels, twin.false_pixels), (0, 0), "{name}");
        assert!(q.coverage > 0.5, "{name}: coverage {}", q.coverage);
        assert!(
            (q.coverage - twin.coverage).abs() < 0.002,
            "{name}: {} vs {}",
            q.coverage,
            twin.coverage
        );
    }
}

/// `auto` takes the CPU on lavapipe, so corpus meshes would never cook on the GPU path: force it,
/// and expect the CPU path's occluder and no false pixel from any view not below the mesh.
#[test]
fn corpus_meshes_cooked_on_the_gpu_match_the_cpu_path() {
    if gpu::device_for_tests().is_none() {
        return;
    }
    let Some(dir) = common::corpus() else { return };
    for name in ["spot.obj", "bunny-holes.obj", "kenney-building-small-a.glb"] {
        let mesh = load_file(&dir.join(name), &IngestLimits::default())
            .expect("corpus mesh loads")
            .0;
        let (g, c) = (cook_on("gpu", mesh.clone()), cook_on("cpu", mesh));
        let (q, twin) = (g.report.quality.as_ref().unwrap(), c.report.quality.as_ref().unwrap());
        eprintln!(
            "{name}: gpu stages {:?}, {} triangles, coverage {:.2}% (cpu {:.2}%), false pixels {} / {} non-below",
            g.report.gpu_stages,
            q.occluder_triangles,
            q.coverage * 100.0,
            twin.coverage * 100.0,
            q.false_pixels,
            q.false_pixels_non_below
        );
        for stage in ["surface", "inside", "eval"] {
            assert!(g.report.gpu_stages.contains(&stage), "{name}: {stage} not on the GPU");
        }
        assert_eq!(g.report.occluder.triangles, c.report.occluder.triangles, "{name}");
        assert_eq!(q.false_pixels_non_below, 0, "{name}");
        if g.report.input.topology.boundary_edges == 0 {
            assert_eq!(q.false_pixels, 0, "{name}");
        }
    }
}

#[test]
fn a_stage_that_cannot_fit_the_device_fails_that_call_alone() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let mesh = torus(1.0, 0.4, 24, 12);
    let (lo, hi) = mesh.bounds();
    let grid = Grid::fit(lo, hi, 48);
    // A binding smaller than one layer of the grid: the stage must refuse, not write out of
    // bounds or crash, and the device must serve the next call.
    let tiny = gpu.with_max_binding(16);
    let error = surface::gpu::voxelize(&tiny, &mesh, &grid).expect_err("one layer cannot fit");
    assert!(matches!(error, GpuError::OutOfMemory(_)), "{error}");
    assert!(error.to_string().contains("storage binding"), "{error}");
    let next = surface::gpu::voxelize(&gpu, &mesh, &grid).expect("the device still works");
    assert_eq!(next, surface::voxelize(&mesh, &grid));
}

#[test]
fn the_eval_on_the_gpu_counts_the_false_pixels_of_a_wrong_occluder_as_the_cpu_does() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let original = torus(1.0, 0.4, 48, 24);
    // A slab through the hole and out past the rim: wrong in most views.
    let wrong = cuboid(Vec3::new(-1.6, -0.1, -1.6), Vec3::new(1.6, 0.1, 1.6), &[]);
    let settings = common::defaults().eval;
    let run =
        |gpu: Option<&Gpu>| occluder_cook::eval::evaluate(&original, &[], &wrong, &settings, gpu).expect("evaluates");
    let (g, c) = (run(Some(&gpu)), run(None));
    eprintln!(
        "false pixels: gpu {} cpu {}; coverage gpu {:.4} cpu {:.4}",
        g.false_pixels, c.false_pixels, g.coverage, c.coverage
    );
    assert!(c.false_pixels > 10_000, "{}", c.false_pixels);
    let gap = g.false_pixels.abs_diff(c.false_pixels) as f64;
    assert!(
        gap <= 0.005 * c.false_pixels as f64,
        "gpu {} cpu {}",
        g.false_pixels,
        c.false_pixels
    );
    assert!((g.coverage - c.coverage).abs() < 0.002);
}

#[test]
fn cpsv_on_the_gpu_matches_its_cpu_twin() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let mut meshes = vec![
        ("torus".to_string(), torus(1.0, 0.4, 48, 24), 32),
        (
            "open building".to_string(),
            cuboid(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 1.5, 1.0), &[2]),
            24,
        ),
    ];
    if let Some(dir) = common::corpus() {
        let (mesh, _) = load_file(&dir.join("spot.obj"), &IngestLimits::default()).expect("corpus mesh loads");
        meshes.push(("spot.obj".into(), mesh, 64));
    }
    let settings = common::defaults().cook.cpsv();
    for (name, mut mesh, resolution) in meshes {
        let topology = orient_closed_components(&mut mesh);
        let (lo, hi) = mesh.bounds();
        let grid = Grid::fit(lo, hi, resolution);
        let surface = surface::voxelize(&mesh, &grid);
        let run =
            |gpu| classify(InsideMethod::Cpsv, &mesh, &topology, &grid, &surface, &settings, gpu).expect("cpsv runs");
        let (g, c) = (run(Some(&gpu)), run(None));
        let d = differ(&g.solid, &c.solid);
        eprintln!(
            "{name} @{resolution}: cpsv differs at {d} of {} voxels; gpu {:?}, cpu {:?}",
            grid.len(),
            g.cpsv,
            c.cpsv
        );
        assert!(d as f64 <= 0.001 * grid.len() as f64, "{name}: {d} voxels differ");
        assert!(
            c.solid.iter().zip(&surface).any(|(&s, &t)| s && !t),
            "{name}: nothing inside"
        );
    }
}

#[test]
fn exposed_voxels_on_the_gpu_match_their_cpu_twin() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let mut meshes = vec![(
        "open box".to_string(),
        cuboid(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 1.0), &[3]),
    )];
    if let Some(dir) = common::corpus() {
        for name in ["bunny-holes.obj", "kenney-building-small-a.glb", "sphere-with-hole.stl"] {
            meshes.push((
                name.into(),
                load_file(&dir.join(name), &IngestLimits::default())
                    .expect("corpus mesh loads")
                    .0,
            ));
        }
    }
    for (name, mut mesh) in meshes {
        let (lo, hi) = mesh.bounds();
        let grid = Grid::fit(lo, hi, 64);
        let topology = orient_closed_components(&mut mesh);
        let field = WindingField::new(&mesh, &topology.boundary);
        // Every voxel, so that every corner of the grid is tested.
        let every = vec![true; grid.len()];
        let views = OpenViews::new(&mesh, &topology.boundary, || &field, None, (&grid, &every)).expect("CPU views");
        let (mut on_gpu, mut on_cpu) = (every.clone(), every.clone());
        let removed = views
            .remove_exposed(&grid, &mut on_gpu, Some(&gpu))
            .expect("GPU corners");
        let twin = views.remove_exposed(&grid, &mut on_cpu, None).expect("CPU corners");
        let differing = differ(&on_gpu, &on_cpu);
        eprintln!("{name}: {removed} exposed on the GPU, {twin} on the CPU, {differing} voxels differ");
        assert!(twin > 0, "{name}: the views see into the grid");
        // f32 against f64 projections may differ at corners within rounding of a pixel's depth,
        // but only towards removing more: a voxel the CPU finds exposed must go on the GPU too.
        let kept_on_gpu_only = on_gpu.iter().zip(&on_cpu).filter(|&(&g, &c)| g && !c).count();
        assert_eq!(kept_on_gpu_only, 0, "{name}: the GPU keeps exposed voxels");
    }
}

/// Every surface voxel of a bricked grid with its facing bits, in order.
fn brick_voxels(grid: &BrickGrid) -> Vec<(IVec3, u8)> {
    let mut voxels: Vec<(IVec3, u8)> = grid.surface_voxels().collect();
    voxels.sort_by_key(|&(v, _)| (v.x, v.y, v.z));
    voxels
}

#[test]
fn bricks_on_the_gpu_match_their_cpu_twin() {
    let Some(gpu) = gpu::device_for_tests() else { return };
    let slanted = Mesh {
        positions: vec![
            Vec3::new(0.3, 0.2, 0.1),
            Vec3::new(17.5, 3.1, 9.0),
            Vec3::new(4.0, 15.2, 12.7),
        ],
        triangles: vec![[0, 1, 2]],
    };
    // Walls seen from within: the inside stage finds the space they enclose.
    let mut walls = cuboid(Vec3::new(-1.0, -1.0, -1.0), Vec3::new(21.0, 5.0, 13.0), &[]);
    walls.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    let rooms = concat(&[
        walls,
        cuboid(Vec3::ZERO, Vec3::new(20.0, 0.2, 12.0), &[]),
        cuboid(Vec3::new(9.0, 0.0, 0.0), Vec3::new(11.0, 3.0, 4.0), &[]),
        torus(1.0, 0.4, 48, 24),
    ]);
    let mut maps = vec![
        ("slanted triangle".to_string(), slanted, 0.37),
        ("rooms".into(), rooms, 0.05),
    ];
    if let Some(levels) = common::levels() {
        let path = levels.join("soups/curvedm.obj");
        let (map, _) = load_file(&path, &IngestLimits::default()).expect("soup map loads");
        let (lo, hi) = map.bounds();
        maps.push((
            "soups/curvedm.obj".into(),
            map,
            f64::from((hi - lo).max_element()) / 512.0,
        ));
    }
    for (name, map, voxel_size) in &maps {
        let on_cpu = BrickGrid::voxelize(map, *voxel_size, None).expect("CPU bricks");
        let on_gpu = BrickGrid::voxelize(map, *voxel_size, Some(&gpu)).expect("GPU bricks");
        assert_eq!(on_cpu.stats(), on_gpu.stats(), "{name}");
        assert!(brick_voxels(&on_cpu) == brick_voxels(&on_gpu), "{name}: voxels differ");
        assert!(
            inside_voxels(&on_cpu) == inside_voxels(&on_gpu),
            "{name}: inside differs"
        );
        assert!(
            name == "slanted triangle" || !inside_voxels(&on_cpu).is_empty(),
            "{name}: nothing inside"
        );
        eprintln!("{name}: {:?}", on_cpu.stats());
    }
    // A binding of 128 bricks' voxels: the same grid, in chunks.
    let (name, map, voxel_size) = &maps[1];
    let chunked = BrickGrid::voxelize(map, *voxel_size, Some(&gpu.with_max_binding(128 * 512))).expect("chunks");
    let whole = BrickGrid::voxelize(map, *voxel_size, None).expect("CPU bricks");
    assert!(brick_voxels(&chunked) == brick_voxels(&whole), "{name} in chunks");
    assert!(
        inside_voxels(&chunked) == inside_voxels(&whole),
        "{name}: inside in chunks"
    );
}

/// The voxels a bricked grid finds inside the map, over a lattice of every third voxel (one
/// not a divisor of the bricks' side, so it meets every place within a brick).
fn inside_voxels(grid: &BrickGrid) -> Vec<IVec3> {
    let dims = grid.dims();
    let mut inside = Vec::new();
    for x in (0..dims.x).step_by(3) {
        for y in (0..dims.y).step_by(3) {
            for z in (0..dims.z).step_by(3) {
                let v = IVec3::new(x, y, z);
                if grid.inside(v) {
                    inside.push(v);
                }
            }
        }
    }
    inside
}
