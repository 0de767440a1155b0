mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};
use occluder_cook::service::client;
use std::io::IsTerminal;
use std::sync::Mutex;

/// Conservative occluders for game meshes: a few dozen triangles inside the mesh that cover
/// as much of its silhouette as they can.
#[derive(Parser)]
#[command(name = "occluder-cook", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Cook one mesh (.glb, .gltf, .fbx, .obj, .ply, .stl) into an occluder GLB.
    Cook(cli::cook::CookArgs),
    /// Write a mesh as the cook reads it (placed, in metres with +Y up, welded) as a plain GLB.
    Convert(cli::convert::ConvertArgs),
    /// Cook the built-in sample, a torus, with evaluation: a check that everything works.
    Demo(cli::demo::DemoArgs),
    /// Judge any occluder mesh against its original.
    Eval(cli::eval::EvalArgs),
    /// Run the cook service: the HTTP API, a pool of workers and the sled cache.
    Serve(cli::serve::ServeArgs),
    /// Run cook workers only, taking jobs from NATS JetStream (a worker node of a cluster).
    Worker(cli::worker::WorkerArgs),
    /// Print the content key of a mesh with these settings, offline (to HEAD a server first).
    Key(cli::key::KeyArgs),
    /// Upload meshes to a server. Exit codes: 0 done, 1 local error, 2 rejected by the server,
    /// 3 a job failed, 4 server unreachable or failing.
    Submit(cli::submit::SubmitArgs),
    /// Download a cooked occluder by key (exit codes as submit).
    Fetch(cli::fetch::FetchArgs),
    /// Make API tokens for a server with service.auth = "tokens".
    Token(cli::token::TokenArgs),
    /// Bake a level (a JSON manifest, an OBJ whose groups are the instances, or a glTF or FBX
    /// scene whose mesh nodes are) into a few merged occluder batches, cooking each unique mesh
    /// once through the same sled cache as the service.
    Level(cli::level::LevelArgs),
    /// Culling test of a level's occluders (ours or any other mesh): cameras inside the level,
    /// instance boxes against a low-resolution depth buffer of the occluders, and ground truth
    /// from the real meshes at 512 pixels.
    CullEval(cli::cull_eval::CullEvalArgs),
    /// Cook and evaluate every mesh of a corpus; print a table and write JSON.
    Bench(cli::bench::BenchArgs),
    /// Fuzz ingest: mutate the corpus's meshes and read them; any panic or slow input is a
    /// finding, written to a folder, and the exit code is 1.
    Fuzz(cli::fuzz::FuzzArgs),
    /// Soak a server of this binary: mixed load for a set time (new meshes, duplicates, cached
    /// GETs, malformed and oversized bodies, calls without a token), killed with SIGKILL and
    /// restarted on a schedule; jobs lost, wrong bytes, RSS and cached-GET p99 per minute.
    Soak(cli::soak::SoakArgs),
}

fn main() {
    // Mesa's device-select layer probes for a display (and complains without one); wgpu picks
    // the adapter itself. Set before any thread starts, as set_var requires.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: no other thread exists yet.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
    keep_freed_memory();
    let parsed = Cli::parse();
    // The fuzzer reads thousands of broken files a second: their warnings are noise. rustls
    // warns once per connection about what a client sent (an IP address as SNI, say): a client
    // could fill the log, so only its errors show.
    let default_level = if matches!(parsed.command, Command::Fuzz(_)) {
        "error"
    } else {
        "warn,rustls=error"
    };
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        // Colour codes only for a terminal: not in a log file, a pipe or a container's log.
        .with_ansi(std::io::stderr().is_terminal())
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| default_level.into()))
        .without_time()
        .init();
    std::panic::set_hook(Box::new(remember_panic));
    let outcome = std::panic::catch_unwind(|| run(parsed)).unwrap_or_else(|_| {
        let panic = LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()).take();
        Err(anyhow::anyhow!(panic.unwrap_or_else(|| "internal error".into())))
    });
    if let Err(e) = outcome {
        eprintln!("error: {e:#}");
        let code = e.downcast_ref::<client::Exit>().map_or(1, client::Exit::code);
        std::process::exit(code);
    }
}

/// Keeps the heap a cook frees for what it allocates next. glibc otherwise maps each large block
/// afresh and hands the top of the heap back once it grows past a threshold, so stages that free
/// and allocate the same megabytes again and again (the quads' passes, the selection's masks)
/// have the kernel fault in and zero new pages each time: a fandisk cook took 6.7 k page faults,
/// 5.1 k with this. The service hands a job's memory back when it ends (malloc_trim), whatever
/// these thresholds.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt takes no pointers; it sets two of the allocator's thresholds, before any
    // other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

/// The last panic, as one line, for `main` to print should it reach it: panics that are caught
/// on the way (an unreadable upload in the service) print nothing.
static LAST_PANIC: Mutex<Option<String>> = Mutex::new(None);

fn remember_panic(info: &std::panic::PanicHookInfo) {
    let stage = occluder_cook::cook::last_stage().unwrap_or("startup");
    let line = format!("internal error in stage `{stage}`: {}", occluder_cook::panic_text(info));
    tracing::debug!("{line}");
    *LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()) = Some(line);
}

fn run(parsed: Cli) -> Result<()> {
    match parsed.command {
        Command::Cook(args) => cli::cook::run(args),
        Command::Convert(args) => cli::convert::run(args),
        Command::Fuzz(args) => cli::fuzz::run(args),
        Command::Token(args) => cli::token::run(args),
        Command::Soak(args) => cli::soak::run(args),
        Command::Demo(args) => cli::demo::run(args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Serve(args) => cli::serve::run(args),
        Command::Worker(args) => cli::worker::run(args),
        Command::Key(args) => cli::key::run(args),
        Command::Submit(args) => cli::submit::run(args),
        Command::Fetch(args) => cli::fetch::run(args),
        Command::Level(args) => cli::level::run(args),
        Command::CullEval(args) => cli::cull_eval::run(args),
        Command::Bench(args) => cli::bench::run(args),
    }
}
