use super::{SettingsArgs, write};
use anyhow::{Context, Result};
use clap::Args;
use occluder_cook::eval;
use occluder_cook::geom::openings::close_openings;
use occluder_cook::gpu;
use occluder_cook::mesh::{self, topology::orient_closed_components};
use std::path::PathBuf;

#[derive(Args)]
pub struct EvalArgs {
    original: PathBuf,
    occluder: PathBuf,
    /// Also write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write a PNG sheet of four views: the original in grey, the occluder over it, false
    /// pixels in red.
    #[arg(long, value_name = "PNG")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: EvalArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let limits = settings.ingest_limits();
    let (mut original_mesh, _) = mesh::load_file(&args.original, &limits)?;
    let mut topology = orient_closed_components(&mut original_mesh);
    let width = settings.cook.smallest_hole;
    let mut openings = Vec::new();
    if width > 0.0 {
        let (closed, closed_openings) = close_openings(&original_mesh, &topology.boundary, width);
        println!(
            "judged against the original with {} openings narrower than smallest_hole {width} closed",
            closed_openings.len()
        );
        if !closed_openings.is_empty() {
            original_mesh = closed;
            topology = orient_closed_components(&mut original_mesh);
        }
        openings = closed_openings;
    }
    let occluder_mesh = match mesh::load_file(&args.occluder, &limits) {
        Ok((m, _)) => m,
        // An empty occluder is a fair answer for a mesh with no volume.
        Err(mesh::IngestError::Empty(_)) => mesh::Mesh::default(),
        Err(e) => return Err(e).with_context(|| format!("occluder {}", args.occluder.display())),
    };
    let placement = gpu::for_choice(settings.cook.device)?;
    let gpu = placement.gpu.as_deref().filter(|_| settings.eval.draws_on_gpu());
    let (q, why_cpu) =
        eval::evaluate_where_it_can(&original_mesh, &topology.boundary, &occluder_mesh, &settings.eval, gpu)?;
    let rendered_on = match (gpu, why_cpu) {
        (_, Some(why)) => format!("cpu (the GPU could not: {why})"),
        (Some(gpu), None) => gpu.name(),
        (None, None) => "cpu".into(),
    };
    println!("rendered on        {rendered_on}");
    println!("triangles          {}", q.occluder_triangles);
    let over = match q.views_seeing {
        seeing if seeing == q.views => format!("{seeing} views"),
        seeing => format!("the {seeing} of {} views that see the original", q.views),
    };
    match q.views_seeing {
        0 => println!("coverage           none measured: no view sees the original"),
        _ => println!(
            "coverage           {:.2}% (min {:.2}%) over {over}",
            q.coverage * 100.0,
            q.coverage_min * 100.0
        ),
    }
    println!("false pixels       {} (all views)", q.false_pixels);
    println!(
        "false pixels       {} ({} non-below views)",
        q.false_pixels_non_below, q.views_non_below
    );
    println!("outside samples    {:.3}% of {}", q.outside_samples * 100.0, q.samples);
    if let Some(path) = args.json {
        write(&path, &serde_json::to_vec_pretty(&q)?)?;
    }
    if let Some(path) = &args.preview {
        use occluder_cook::eval::preview;
        let caption = preview::Caption {
            name: super::file_name(&args.original),
            triangles_in: original_mesh.triangles.len(),
            triangles_out: occluder_mesh.triangles.len(),
            judged: Some((q.coverage, q.false_pixels, q.views)),
            openings: openings.iter().flat_map(|o| o.outline.clone()).collect(),
        };
        // Any mesh may be judged: it is drawn as one solid.
        let occluder = preview::pieces_of_mesh(&occluder_mesh, preview::Piece::Solid);
        super::write_preview(path, &original_mesh, &occluder, &caption)?;
    }
    Ok(())
}
