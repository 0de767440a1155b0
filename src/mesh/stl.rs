//! STL, ASCII and binary.
//!
//! Written here rather than taken from stl_io because the lenient readings our users need
//! (no `endsolid`, facets without normals, binary files whose header starts with "solid",
//! polygons as fans) are rejected by it.

use super::{IngestError, RawMesh};
use glam::Vec3;

const HEADER: usize = 84;
const RECORD: usize = 50;

pub fn read(bytes: &[u8]) -> Result<RawMesh, IngestError> {
    if bytes.is_empty() {
        return Err(IngestError::malformed("STL", "the file is empty"));
    }
    let declared =
        (bytes.len() >= HEADER).then(|| u32::from_le_bytes(bytes[80..84].try_into().expect("4 bytes")) as usize);
    // The size test wins over the "solid" prefix: binary headers often begin with it.
    if declared.is_some_and(|n| bytes.len() == HEADER + RECORD * n) {
        return read_binary(bytes);
    }
    let text = std::str::from_utf8(bytes)
        .ok()
        .filter(|t| t.trim_start().starts_with("solid"));
    match (text, declared) {
        (Some(text), _) => read_ascii(text),
        (None, Some(n)) => Err(IngestError::malformed(
            "STL",
            format!(
                "binary header declares {n} triangles ({} bytes) but the file has {} bytes (truncated?)",
                HEADER + RECORD * n,
                bytes.len()
            ),
        )),
        (None, None) => Err(IngestError::malformed(
            "STL",
            "neither ASCII ('solid ...') nor a binary header",
        )),
    }
}

fn read_binary(bytes: &[u8]) -> Result<RawMesh, IngestError> {
    let mut positions = Vec::new();
    for record in bytes[HEADER..].chunks_exact(RECORD) {
        let f = |i: usize| f32::from_le_bytes(record[i..i + 4].try_into().expect("4 bytes"));
        // Bytes 0..12 are the normal, which the winding makes redundant.
        for v in 0..3 {
            let o = 12 + v * 12;
            positions.push(Vec3::new(f(o), f(o + 4), f(o + 8)));
        }
    }
    let count = positions.len() as u64 / 3;
    let mut raw = RawMesh::default();
    raw.append(&positions, (0..count).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]))?;
    Ok(raw)
}

fn err(line: usize, message: String) -> IngestError {
    IngestError::malformed("STL", format!("line {line}: {message}"))
}

/// Consumes the next line, which must be exactly `words`.
fn expect<'a>(
    lines: &mut impl Iterator<Item = (usize, Vec<&'a str>)>,
    words: &[&str],
    previous_line: usize,
    facet: usize,
) -> Result<(), IngestError> {
    match lines.next() {
        Some((_, t)) if t == words => Ok(()),
        Some((m, t)) => Err(err(
            m,
            format!("expected '{}', found '{}'", words.join(" "), t.join(" ")),
        )),
        None => Err(err(previous_line, format!("the file ends inside facet {facet}"))),
    }
}

fn read_ascii(text: &str) -> Result<RawMesh, IngestError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.split_whitespace().collect::<Vec<_>>()))
        .filter(|(_, tokens)| !tokens.is_empty());
    lines.next(); // "solid [name]"
    let mut raw = RawMesh::default();
    let mut polygon: Vec<Vec3> = Vec::new();
    let mut facets = 0usize;
    // A missing `endsolid` is tolerated: the loop just runs out of lines.
    while let Some((n, tokens)) = lines.next() {
        match tokens[0] {
            "endsolid" => break,
            "facet" => facets += 1,
            other => return Err(err(n, format!("expected 'facet' or 'endsolid', found '{other}'"))),
        }
        expect(&mut lines, &["outer", "loop"], n, facets)?;
        polygon.clear();
        let end_line = loop {
            match lines.next() {
                Some((m, t)) if t[0] == "vertex" => {
                    let coords: Vec<f32> = t[1..]
                        .iter()
                        .map(|s| s.parse::<f32>())
                        .collect::<Result<_, _>>()
                        .map_err(|e| err(m, format!("bad vertex coordinate: {e}")))?;
                    if coords.len() != 3 {
                        return Err(err(m, format!("a vertex needs 3 coordinates, found {}", coords.len())));
                    }
                    polygon.push(Vec3::new(coords[0], coords[1], coords[2]));
                }
                Some((m, t)) if t == ["endloop"] => break m,
                Some((m, t)) => {
                    return Err(err(
                        m,
                        format!("expected 'vertex' or 'endloop', found '{}'", t.join(" ")),
                    ));
                }
                None => return Err(err(n, format!("the file ends inside facet {facets}"))),
            }
        };
        if polygon.len() < 3 {
            return Err(err(
                end_line,
                format!("facet {facets} has {} vertices; a facet needs 3", polygon.len()),
            ));
        }
        if polygon.len() > 3 {
            raw.warnings.push(format!(
                "facet {facets} has {} vertices; read as a fan of {} triangles",
                polygon.len(),
                polygon.len() - 2
            ));
        }
        let fan = (2..polygon.len() as u64).map(|i| [0, i - 1, i]);
        raw.append(&polygon, fan)?;
        expect(&mut lines, &["endfacet"], end_line, facets)?;
    }
    Ok(raw)
}
