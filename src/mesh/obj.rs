//! Wavefront OBJ through tobj: every group and object, polygons fan-triangulated.

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
    let options = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let geometry = geometry_lines(bytes);
    let (models, _) = tobj::load_obj_buf(&mut &*geometry, &options, |_| Ok(Default::default()))
        .map_err(|e| IngestError::malformed("OBJ", e.to_string()))?;
    let mut groups = Vec::with_capacity(models.len());
    for model in &models {
        let mut raw = RawMesh::default();
        let positions: Vec<Vec3> = model
            .mesh
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let triangles = model
            .mesh
            .indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]].map(u64::from));
        raw.append(&positions, triangles)?;
        groups.push((model.name.clone(), raw));
    }
    Ok(groups)
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
