//! Wavefront OBJ through tobj: every group and object, polygons fan-triangulated. The common
//! files (positions, faces that point back at them, texture and normal lines, groups) take a
//! reader of ours that gives what tobj gives a few times faster; anything else goes to tobj,
//! which reads it or refuses it with its own message.

use super::{IngestError, RawMesh};
use glam::Vec3;
use std::borrow::Cow;

/// Every group and object as one mesh.
pub fn read(bytes: &[u8]) -> Result<RawMesh, IngestError> {
    let mut raw = RawMesh::default();
    for (_, group) in read_groups(bytes)? {
        raw.append(&group.positions, group.triangles.iter().map(|t| t.map(u64::from)))?;
    }
    Ok(raw)
}

/// Each group or object on its own, with its name.
pub fn read_groups(bytes: &[u8]) -> Result<Vec<(String, RawMesh)>, IngestError> {
    let geometry = geometry_lines(bytes);
    let models = match read_common(&geometry) {
        Some(models) => models,
        None => read_tobj(&geometry)?,
    };
    let mut groups = Vec::with_capacity(models.len());
    for model in models {
        let mut raw = RawMesh::default();
        raw.append(&model.positions, model.triangles.iter().map(|t| t.map(u64::from)))?;
        groups.push((model.name, raw));
    }
    Ok(groups)
}

/// A group or object as tobj gives it: its name, the positions its faces use in the order they
/// are first used, and its triangles over them.
#[derive(Debug, PartialEq)]
struct Model {
    name: String,
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

fn read_tobj(geometry: &[u8]) -> Result<Vec<Model>, IngestError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj_buf(&mut &*geometry, &options, |_| Ok(Default::default()))
        .map_err(|e| IngestError::malformed("OBJ", e.to_string()))?;
    Ok(models
        .into_iter()
        .map(|model| Model {
            name: model.name,
            positions: model
                .mesh
                .positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2]))
                .collect(),
            triangles: model.mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        })
        .collect())
}

/// The models tobj reads from `geometry` (with our options), read with the same string
/// functions, where every line is one of: blank; `v` and three numbers; `vt` and at least two,
/// or `vn` and at least three; `f` and three corners or more (`v`, `v/vt`, `v//vn` or
/// `v/vt/vn`, each index pointing back at a line already read); `o` or `g`; any other keyword
/// but `l` and the material ones, which tobj skips too. None where any line is not, or the
/// text is not UTF-8, for tobj to read.
fn read_common(geometry: &[u8]) -> Option<Vec<Model>> {
    let text = std::str::from_utf8(geometry).ok()?;
    match text.is_ascii() {
        true => read_lines(text, |line| AsciiWords { rest: line }),
        false => read_lines(text, str::split_whitespace),
    }
}

/// [`read_common`] of UTF-8 text, each line's words split by `words`.
fn read_lines<'a, W: Iterator<Item = &'a str>>(text: &'a str, words: impl Fn(&'a str) -> W) -> Option<Vec<Model>> {
    let mut models = Vec::new();
    let mut name = "unnamed_object";
    let mut positions: Vec<Vec3> = Vec::new();
    let (mut texcoords, mut normals) = (0usize, 0usize);
    // Each position's index in the model being read, u32::MAX where it uses none yet; the
    // positions it uses, in that order; its triangles over them.
    let mut local: Vec<u32> = Vec::new();
    let mut used: Vec<usize> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut corners: Vec<u32> = Vec::new();
    // The model read so far, as it ends.
    let finish =
        |name: &str, positions: &[Vec3], used: &mut Vec<usize>, triangles: &mut Vec<[u32; 3]>, local: &mut [u32]| {
            for &i in used.iter() {
                local[i] = u32::MAX;
            }
            Model {
                name: name.to_string(),
                positions: used.drain(..).map(|i| positions[i]).collect(),
                triangles: std::mem::take(triangles),
            }
        };
    for line in text.split('\n') {
        let mut words = words(line);
        let Some(keyword) = words.next() else { continue };
        match keyword {
            "v" => {
                let mut number = || words.next()?.parse::<f32>().ok();
                let p = Vec3::new(number()?, number()?, number()?);
                if words.next().is_some() {
                    return None;
                }
                positions.push(p);
                local.push(u32::MAX);
            }
            "vt" | "vn" => {
                let needed = if keyword == "vt" { 2 } else { 3 };
                for _ in 0..needed {
                    words.next()?.parse::<f32>().ok()?;
                }
                *(if keyword == "vt" { &mut texcoords } else { &mut normals }) += 1;
            }
            "f" => {
                corners.clear();
                for word in words {
                    let mut parts = word.split('/');
                    let v = back_index(parts.next(), positions.len())??;
                    // Texture and normal indices point back too: tobj checks them against the
                    // lines read when the model ends.
                    back_index(parts.next(), texcoords)?;
                    back_index(parts.next(), normals)?;
                    if parts.next().is_some() {
                        return None;
                    }
                    if local[v] == u32::MAX {
                        local[v] = used.len() as u32;
                        used.push(v);
                    }
                    corners.push(local[v]);
                }
                if corners.len() < 3 {
                    return None;
                }
                triangles.extend(corners.windows(2).skip(1).map(|pair| [corners[0], pair[0], pair[1]]));
            }
            "o" | "g" => {
                if !triangles.is_empty() {
                    models.push(finish(name, &positions, &mut used, &mut triangles, &mut local));
                }
                // As tobj names it: the line after its first character.
                let first = line.chars().next().map_or(0, char::len_utf8);
                name = match line[first..].trim() {
                    "" => "unnamed_object",
                    named => named,
                };
            }
            "l" | "usemtl" | "mtllib" => return None,
            _ => {}
        }
    }
    models.push(finish(name, &positions, &mut used, &mut triangles, &mut local));
    Some(models)
}

/// The words of ASCII text as `str::split_whitespace` splits it, a byte at a time.
struct AsciiWords<'a> {
    rest: &'a str,
}

impl<'a> Iterator for AsciiWords<'a> {
    type Item = &'a str;

    fn next(&mut self) -> Option<&'a str> {
        // ASCII's Unicode white space: tab, line feed, vertical tab, form feed, return, space.
        let space = |b: &u8| matches!(b, b'\t'..=b'\r' | b' ');
        let bytes = self.rest.as_bytes();
        let start = bytes.iter().position(|b| !space(b))?;
        let end = bytes[start..].iter().position(space).map_or(bytes.len(), |n| start + n);
        let word = &self.rest[start..end];
        self.rest = &self.rest[end..];
        Some(word)
    }
}

/// An index of a face corner into `count` lines read so far, as tobj reads it: from 1, or from
/// the end where negative. Some(None) where there is none; None where it points at no line read.
fn back_index(part: Option<&str>, count: usize) -> Option<Option<usize>> {
    match part {
        None | Some("") => Some(None),
        Some(part) => {
            let i: isize = part.parse().ok()?;
            let i = match i < 0 {
                true => count.checked_sub(i.unsigned_abs())?,
                false => i.unsigned_abs().checked_sub(1)?,
            };
            (i < count).then_some(Some(i))
        }
    }
}

/// The file's lines without material lines, with CRLF endings as LF and continued lines joined.
/// Materials do not change geometry, and tobj rejects some material lines that other readers
/// accept (an empty `usemtl`); tobj's own joining fails on some exporters' output. A file with
/// none of those is the bytes as they are, not copied.
fn geometry_lines(bytes: &[u8]) -> Cow<'_, [u8]> {
    let rewrite = memchr::memchr2(b'\r', b'\\', bytes).is_some()
        || memchr::memmem::find(bytes, b"usemtl").is_some()
        || memchr::memmem::find(bytes, b"mtllib").is_some();
    if !rewrite {
        return Cow::Borrowed(bytes);
    }
    let mut geometry = Vec::with_capacity(bytes.len());
    for line in bytes.split(|&b| b == b'\n') {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        let start = line.trim_ascii_start();
        if start.starts_with(b"usemtl") || start.starts_with(b"mtllib") {
            continue;
        }
        match line.trim_ascii_end().strip_suffix(b"\\") {
            Some(continued) => {
                geometry.extend_from_slice(continued);
                geometry.push(b' ');
            }
            None => {
                geometry.extend_from_slice(line);
                geometry.push(b'\n');
            }
        }
    }
    Cow::Owned(geometry)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Our reader where it reads, tobj where it does not: the same models either way.
    fn both(text: &str) -> Option<Vec<Model>> {
        let ours = read_common(text.as_bytes());
        if let Some(models) = &ours {
            assert_eq!(Some(models), read_tobj(text.as_bytes()).ok().as_ref(), "{text}");
        }
        ours
    }

    /// A random file of the lines our reader takes: indices positive and negative, with and
    /// without texture and normal indices, polygons, groups named and not, odd spacing.
    fn random_obj(rng: &mut fastrand::Rng) -> String {
        let mut text = String::new();
        let (mut v, mut vt, mut vn) = (0usize, 0usize, 0usize);
        let space = |rng: &mut fastrand::Rng| [" ", "  ", "\t", " \x0b", "\x0c "][rng.usize(0..5)];
        for _ in 0..rng.usize(1..80) {
            let s = space(rng);
            match rng.usize(0..12) {
                0..=3 => {
                    let mut n = || format!("{}", (rng.f32() - 0.5) * 10.0);
                    let (x, y, z) = (n(), n(), n());
                    text += &format!("v{s}{x}{s}{y}{s}{z}\n");
                    v += 1;
                }
                4 => {
                    text += &format!("vt {} {}\n", rng.f32(), rng.f32());
                    vt += 1;
                }
                5 => {
                    text += &format!("vn 0 {} 1\n", rng.f32());
                    vn += 1;
                }
                6..=8 if v > 0 => {
                    text += "f";
                    let (with_vt, with_vn) = (vt > 0 && rng.bool(), vn > 0 && rng.bool());
                    for _ in 0..rng.usize(3..7) {
                        let index = |rng: &mut fastrand::Rng, count: usize| match rng.bool() {
                            true => format!("{}", rng.usize(1..=count)),
                            false => format!("-{}", rng.usize(1..=count)),
                        };
                        text += s;
                        text += &index(rng, v);
                        match (with_vt, with_vn) {
                            (true, true) => text += &format!("/{}/{}", index(rng, vt), index(rng, vn)),
                            (true, false) => text += &format!("/{}", index(rng, vt)),
                            (false, true) => text += &format!("//{}", index(rng, vn)),
                            (false, false) => {}
                        }
                    }
                    text += "\n";
                }
                9 => text += ["o part", "g", "g  two words \t", "o\x0bx", "  g spaced", "o caf\u{e9}"][rng.usize(0..6)],
                10 => text += ["# a comment", "s 1", "", "   "][rng.usize(0..4)],
                _ => {}
            }
            if !text.ends_with('\n') {
                text += "\n";
            }
        }
        text
    }

    #[test]
    fn the_files_our_reader_takes_give_what_tobj_gives() {
        let mut rng = fastrand::Rng::with_seed(54);
        for _ in 0..2_000 {
            let text = random_obj(&mut rng);
            assert!(both(&text).is_some(), "{text}");
        }
    }

    #[test]
    fn anything_else_is_left_to_tobj() {
        for text in [
            // An index pointing ahead, which tobj checks only once the model ends.
            "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\nvt 0 0\n",
            // A fourth coordinate, colours, too few numbers.
            "v 0 0 0 2\n",
            "v 0 0 0 1 0 0\n",
            "v 0 0\n",
            "vt 0\n",
            // Lines, points and faces of two corners; a fourth index; index 0.
            "v 0 0 0\nv 1 0 0\nl 1 2\n",
            "v 0 0 0\nv 1 0 0\nf 1 2\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n",
            // Material lines, and a number that is not one.
            "usemtl wood\n",
            "v 0 0 x\n",
        ] {
            assert!(read_common(text.as_bytes()).is_none(), "{text}");
        }
        // Nor UTF-8.
        assert!(read_common(b"o \xff\n").is_none());
    }

    /// Every OBJ of the shared corpus and levels goes through our reader, to tobj's models.
    #[test]
    fn the_corpus_objs_take_our_reader() {
        let shared = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared");
        if !shared.is_dir() {
            assert!(std::env::var_os("CI").is_none(), "../shared not found under CI");
            eprintln!("../shared not found: the corpus OBJs were not read");
            return;
        }
        let mut read = 0;
        for folder in ["meshes", "levels/godot-rooms", "levels/pandora", "levels/soups"] {
            for entry in std::fs::read_dir(shared.join(folder)).expect("a shared folder") {
                let path = entry.expect("an entry").path();
                if path.extension().is_some_and(|e| e == "obj") {
                    let bytes = std::fs::read(&path).expect("readable");
                    let geometry = geometry_lines(&bytes);
                    let ours = read_common(&geometry).unwrap_or_else(|| panic!("{} left to tobj", path.display()));
                    assert_eq!(ours, read_tobj(&geometry).expect("tobj reads it"), "{}", path.display());
                    read += 1;
                }
            }
        }
        assert!(read >= 10, "{read} OBJ files");
    }
}
