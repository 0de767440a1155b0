//! The layout keeps its layers: read from the sources' own `crate::` paths, no top-level module
//! reaches one that reaches back (no cycles), the device layer knows no stage, levels know no
//! service, and no function is longer than 100 lines.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn sources(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).expect("src reads") {
        let path = entry.expect("entry reads").path();
        if path.is_dir() {
            files.extend(sources(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            files.push(path);
        }
    }
    files
}

/// The code of a file without its comments and its test module.
fn code(path: &Path) -> String {
    let text = std::fs::read_to_string(path).expect("source reads");
    let text = text.split("#[cfg(test)]").next().unwrap_or_default();
    text.lines()
        .map(|l| l.split("//").next().unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n")
}

/// Top-level module -> the top-level modules its files name through `crate::`.
fn imports() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for path in sources(&src) {
        let relative = path.strip_prefix(&src).expect("under src");
        let top = relative
            .components()
            .next()
            .expect("a file")
            .as_os_str()
            .to_string_lossy();
        let top = top.trim_end_matches(".rs").to_string();
        let code = code(&path);
        for (i, _) in code.match_indices("crate::") {
            let name: String = code[i + 7..]
                .chars()
                .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                .collect();
            if !name.is_empty() && name != top {
                graph.entry(top.clone()).or_default().insert(name);
            }
        }
    }
    graph
}

#[test]
fn no_module_imports_one_that_imports_it_back() {
    let graph = imports();
    // Everything each module reaches, directly or not.
    for start in graph.keys() {
        let mut seen = BTreeSet::new();
        let mut next: Vec<&String> = graph[start].iter().collect();
        while let Some(m) = next.pop() {
            assert_ne!(m, start, "{start} reaches itself: {graph:?}");
            if seen.insert(m.clone()) {
                next.extend(graph.get(m).into_iter().flatten());
            }
        }
    }
}

#[test]
fn the_device_knows_no_stage_and_levels_know_no_service() {
    let graph = imports();
    let gpu = graph.get("gpu").cloned().unwrap_or_default();
    for stage in ["voxel", "eval", "occluder", "level", "cook", "geom"] {
        assert!(!gpu.contains(stage), "gpu/ imports {stage}");
    }
    for (module, above) in [("level", "service"), ("store", "service"), ("store", "level")] {
        assert!(!graph[module].contains(above), "{module}/ imports {above}");
    }
}

#[test]
fn no_function_is_longer_than_100_lines() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    for path in sources(&src) {
        let code = code(&path);
        let lines: Vec<&str> = code.lines().collect();
        for (start, line) in lines.iter().enumerate() {
            let head = line.trim_start();
            let is_fn = [
                "fn ",
                "pub fn ",
                "pub(crate) fn ",
                "pub(super) fn ",
                "async fn ",
                "pub async fn ",
            ]
            .iter()
            .any(|p| head.starts_with(p));
            if !is_fn {
                continue;
            }
            // The body ends where the braces opened at or after the signature close.
            let mut depth = 0i32;
            let mut opened = false;
            let end = lines[start..].iter().position(|l| {
                for c in l.chars() {
                    match c {
                        '{' => (depth, opened) = (depth + 1, true),
                        '}' => depth -= 1,
                        _ => {}
                    }
                }
                (opened && depth <= 0) || (!opened && l.trim_end().ends_with(';'))
            });
            let length = end.map_or(0, |e| e + 1);
            assert!(
                length <= 100,
                "{}:{}: `{}` is {length} lines",
                path.display(),
                start + 1,
                head
            );
        }
    }
}
