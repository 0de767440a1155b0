//! A mutation fuzzer for ingest, on stable Rust: seeds in every format are mutated (bits flipped,
//! bytes overwritten, cut short, spliced with another seed, counts and lengths inflated) and read
//! the way the cook and a level read them. Every panic, and every input slower than a bound, is
//! a finding, kept with its bytes.

use crate::mesh::{Format, IngestLimits, load_bytes, load_instances};
use serde::Serialize;
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// One input to mutate.
pub struct Seed {
    pub name: String,
    pub format: Format,
    pub bytes: Vec<u8>,
}

/// Seeds larger than this are skipped: mutating them finds what smaller ones find, slower.
pub const MAX_SEED_BYTES: u64 = 1 << 20;

/// Every mesh file under `dirs` (recursively) up to [`MAX_SEED_BYTES`], sorted by path.
pub fn seeds_from(dirs: &[PathBuf]) -> std::io::Result<Vec<Seed>> {
    let mut files = Vec::new();
    let mut pending: Vec<PathBuf> = dirs.to_vec();
    while let Some(dir) = pending.pop() {
        for entry in std::fs::read_dir(&dir)? {
            let path = entry?.path();
            if path.is_dir() {
                pending.push(path);
            } else if let Ok(format) = Format::from_extension(&path)
                && path.metadata()?.len() <= MAX_SEED_BYTES
            {
                files.push((path, format));
            }
        }
    }
    files.sort_by(|a, b| a.0.cmp(&b.0));
    files.dedup_by(|a, b| a.0 == b.0);
    files
        .into_iter()
        .map(|(path, format)| {
            Ok(Seed {
                name: path.display().to_string(),
                format,
                bytes: std::fs::read(&path)?,
            })
        })
        .collect()
}

/// How long a run is and what counts as a finding.
#[derive(Clone, Debug)]
pub struct FuzzSettings {
    pub inputs: usize,
    pub seed: u64,
    /// An input read more slowly than this is a finding.
    pub max_ms: f64,
    pub limits: IngestLimits,
}

/// A panic or a slow input, with the bytes that caused it.
#[derive(Clone, Serialize)]
pub struct Finding {
    pub kind: &'static str,
    pub format: &'static str,
    pub seed: String,
    pub mutation: String,
    pub message: String,
    pub ms: f64,
    #[serde(skip)]
    pub bytes: Vec<u8>,
}

impl std::fmt::Debug for Finding {
    /// Everything but the bytes, which [`save_findings`] writes out.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} in {} after {} of {} ({:.0} ms, {} bytes): {}",
            self.kind,
            self.format,
            self.mutation,
            self.seed,
            self.ms,
            self.bytes.len(),
            self.message
        )
    }
}

/// What a run did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FuzzReport {
    pub inputs: usize,
    /// Inputs per format.
    pub per_format: std::collections::BTreeMap<&'static str, usize>,
    /// Inputs read as a mesh, and inputs refused with an error.
    pub accepted: usize,
    pub rejected: usize,
    pub slowest_ms: f64,
    pub findings: Vec<Finding>,
}

/// Fuzzes `seeds` in parallel; `progress(done)` is called every thousand inputs.
pub fn run(seeds: &[Seed], settings: &FuzzSettings, progress: &(dyn Fn(usize) + Sync)) -> FuzzReport {
    use rayon::prelude::*;
    assert!(!seeds.is_empty(), "the fuzzer needs at least one seed");
    // Formats take turns, whatever their number of seeds.
    let formats: Vec<Vec<&Seed>> = Format::ALL
        .iter()
        .map(|&f| seeds.iter().filter(|s| s.format == f).collect::<Vec<_>>())
        .filter(|of_format| !of_format.is_empty())
        .collect();
    let done = AtomicUsize::new(0);
    let quiet = QuietPanics::install();
    let outcomes: Vec<Outcome> = (0..settings.inputs)
        .into_par_iter()
        .map(|i| {
            let mut rng = fastrand::Rng::with_seed(settings.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ i as u64);
            let of_format = &formats[i % formats.len()];
            let seed = of_format[rng.usize(..of_format.len())];
            let (mutation, bytes) = mutate(&mut rng, seed, of_format);
            let outcome = read(seed, mutation, bytes, settings);
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            if n.is_multiple_of(1000) {
                progress(n);
            }
            outcome
        })
        .collect();
    drop(quiet);
    let mut report = FuzzReport {
        inputs: outcomes.len(),
        ..Default::default()
    };
    for outcome in outcomes {
        *report.per_format.entry(outcome.format.name()).or_default() += 1;
        report.slowest_ms = report.slowest_ms.max(outcome.ms);
        match outcome.result {
            Ok(true) => report.accepted += 1,
            Ok(false) => report.rejected += 1,
            Err(finding) => report.findings.push(finding),
        }
    }
    report
}

struct Outcome {
    format: Format,
    ms: f64,
    /// Read (true) or refused (false), or a finding.
    result: Result<bool, Finding>,
}

/// Reads `bytes` as the cook does and, for scene formats, as a level does.
fn read(seed: &Seed, mutation: String, bytes: Vec<u8>, settings: &FuzzSettings) -> Outcome {
    let start = Instant::now();
    let caught = std::panic::catch_unwind(|| {
        let cooked = load_bytes(&bytes, seed.format, None, &settings.limits).is_ok();
        if matches!(seed.format, Format::Gltf | Format::Fbx) {
            let _ = load_instances(&bytes, seed.format, None, &settings.limits);
        }
        cooked
    });
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let finding = |kind, message| Finding {
        kind,
        format: seed.format.name(),
        seed: seed.name.clone(),
        mutation: mutation.clone(),
        message,
        ms,
        bytes: bytes.clone(),
    };
    let result = match caught {
        Err(_) => Err(finding("panic", QuietPanics::last().unwrap_or_default())),
        Ok(_) if ms > settings.max_ms => Err(finding("slow", format!("{ms:.0} ms"))),
        Ok(read) => Ok(read),
    };
    Outcome {
        format: seed.format,
        ms,
        result,
    }
}

/// One to three mutations of `seed`, named; `same_format` are the seeds a splice takes from.
fn mutate(rng: &mut fastrand::Rng, seed: &Seed, same_format: &[&Seed]) -> (String, Vec<u8>) {
    let mut bytes = seed.bytes.clone();
    let mut names = Vec::new();
    for _ in 0..rng.usize(1..=3) {
        names.push(mutate_once(rng, same_format, &mut bytes));
    }
    (names.join(" + "), bytes)
}

/// One mutation of `bytes`, named.
fn mutate_once(rng: &mut fastrand::Rng, same_format: &[&Seed], bytes: &mut Vec<u8>) -> &'static str {
    if bytes.is_empty() {
        return "empty";
    }
    // Headers hold the counts and lengths: aim there half the time.
    let at = |rng: &mut fastrand::Rng, len: usize| match rng.bool() {
        true => rng.usize(..len.min(512)),
        false => rng.usize(..len),
    };
    match rng.u8(..6) {
        0 => {
            for _ in 0..rng.usize(1..=8) {
                let i = at(rng, bytes.len());
                bytes[i] ^= 1 << rng.u8(..8);
            }
            "flip bits"
        }
        1 => {
            let i = at(rng, bytes.len());
            let n = rng.usize(1..=16).min(bytes.len() - i);
            rng.fill(&mut bytes[i..i + n]);
            "overwrite bytes"
        }
        2 => {
            bytes.truncate(rng.usize(..bytes.len()));
            "truncate"
        }
        3 => {
            let other = &same_format[rng.usize(..same_format.len())].bytes;
            bytes.truncate(rng.usize(..=bytes.len()));
            if !other.is_empty() {
                bytes.extend_from_slice(&other[rng.usize(..other.len())..]);
            }
            "splice"
        }
        4 => {
            inflate_text_number(rng, bytes);
            "inflate a number"
        }
        _ => {
            inflate_binary_count(rng, bytes);
            "inflate a binary count"
        }
    }
}

/// Replaces a run of ASCII digits (a count, a length, an index) with a huge or edge value.
fn inflate_text_number(rng: &mut fastrand::Rng, bytes: &mut Vec<u8>) {
    let runs: Vec<usize> = (0..bytes.len())
        .filter(|&i| bytes[i].is_ascii_digit() && (i == 0 || !bytes[i - 1].is_ascii_digit()))
        .collect();
    let Some(&start) = runs.get(rng.usize(..runs.len().max(1))) else {
        return;
    };
    let end = (start..bytes.len())
        .find(|&i| !bytes[i].is_ascii_digit())
        .unwrap_or(bytes.len());
    const VALUES: [&str; 7] = [
        "4294967295",
        "2147483647",
        "2000000000",
        "18446744073709551615",
        "0",
        "-1",
        "65536",
    ];
    let value = match rng.bool() {
        // The same width keeps a GLB's chunk lengths true.
        true => "9".repeat(end - start),
        false => VALUES[rng.usize(..VALUES.len())].to_string(),
    };
    bytes.splice(start..end, value.bytes());
}

/// Writes a large little-endian u32 (or u64) over a word: binary counts and lengths.
fn inflate_binary_count(rng: &mut fastrand::Rng, bytes: &mut [u8]) {
    if bytes.len() < 8 {
        return;
    }
    let i = rng.usize(..bytes.len().min(512) - 7) & !3;
    const VALUES: [u64; 5] = [u32::MAX as u64, i32::MAX as u64, 1 << 28, 1 << 40, u64::MAX];
    let value = VALUES[rng.usize(..VALUES.len())];
    match rng.bool() {
        true => bytes[i..i + 4].copy_from_slice(&(value as u32).to_le_bytes()),
        false => bytes[i..i + 8].copy_from_slice(&value.to_le_bytes()),
    }
}

thread_local! {
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

type PanicHook = Box<dyn Fn(&std::panic::PanicHookInfo) + Sync + Send>;

/// While installed, a panic prints nothing and leaves its message and place for its thread.
struct QuietPanics {
    previous: Option<PanicHook>,
}

impl QuietPanics {
    fn install() -> QuietPanics {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(|info| {
            LAST_PANIC.with(|last| *last.borrow_mut() = Some(crate::panic_text(info)));
        }));
        QuietPanics {
            previous: Some(previous),
        }
    }

    fn last() -> Option<String> {
        LAST_PANIC.with(|last| last.borrow_mut().take())
    }
}

impl Drop for QuietPanics {
    fn drop(&mut self) {
        if let Some(previous) = self.previous.take() {
            std::panic::set_hook(previous);
        }
    }
}

/// Writes each finding's bytes into `dir` as `<kind>-<n>.<format>`; returns the paths.
pub fn save_findings(findings: &[Finding], dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    findings
        .iter()
        .enumerate()
        .map(|(n, f)| {
            let path = dir.join(format!("{}-{n}.{}", f.kind, f.format));
            std::fs::write(&path, &f.bytes)?;
            Ok(path)
        })
        .collect()
}
