//! PLY (Stanford), ASCII and binary in either byte order, through ply-rs-bw: the `vertex`
//! element's x, y and z, and the `face` element's index lists, fan-triangulated. Every other
//! element and property (normals, colours, uv) is read past and ignored.

use super::{IngestError, RawMesh};
use glam::Vec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Encoding, Header, Property, PropertyAccess, PropertyAccessResult, PropertyType};

const FORMAT: &str = "PLY";
const INDEX_LISTS: [&str; 2] = ["vertex_indices", "vertex_index"];

pub fn read(bytes: &[u8]) -> Result<RawMesh, IngestError> {
    let malformed = |e: ply_rs_bw::parser::ParseError| IngestError::malformed(FORMAT, e.to_string());
    let (header_text, mut rest) = split_header(bytes)?;
    let header = Parser::<Skipped>::new()
        .read_header(&mut Reader::new(header_text.as_bytes()))
        .map_err(malformed)?;
    check_counts(&header, rest.len())?;
    let mut reader = Reader::new(&mut rest);
    let (mut vertices, mut faces) = (Vec::new(), Vec::new());
    for element in header.elements.values() {
        match element.name.as_str() {
            "vertex" => {
                vertices = Parser::<Vertex>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(malformed)?;
            }
            "face" => {
                faces = Parser::<Face>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(malformed)?;
            }
            _ => {
                Parser::<Skipped>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(malformed)?;
            }
        }
    }
    let positions: Vec<Vec3> = vertices.iter().map(|v| v.0.as_vec3()).collect();
    let mut triangles = Vec::new();
    for face in &faces {
        let index = |i: usize| u64::try_from(face.0[i]).unwrap_or(u64::MAX);
        triangles.extend((2..face.0.len()).map(|i| [index(0), index(i - 1), index(i)]));
    }
    let mut raw = RawMesh::default();
    raw.append(&positions, triangles)?;
    Ok(raw)
}

/// The header, with free text that some exporters write without `comment` (Blender 2.4's
/// "Created by Blender3D ...") made a comment, and the payload after it.
fn split_header(bytes: &[u8]) -> Result<(String, &[u8]), IngestError> {
    const END: &[u8] = b"end_header";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| IngestError::malformed(FORMAT, "no end_header line"))?;
    let line_end = bytes[end..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |n| end + n + 1);
    let text = std::str::from_utf8(&bytes[..line_end])
        .map_err(|_| IngestError::malformed(FORMAT, "the header is not text"))?;
    const KEYWORDS: [&str; 7] = [
        "ply",
        "format",
        "comment",
        "obj_info",
        "element",
        "property",
        "end_header",
    ];
    let mut header = String::with_capacity(text.len());
    for line in text.lines() {
        let keyword = line.split_whitespace().next().unwrap_or("");
        if !KEYWORDS.contains(&keyword) {
            header.push_str("comment ");
        }
        header.push_str(line);
        header.push('\n');
    }
    Ok((header, &bytes[line_end..]))
}

/// Refuses a header whose element counts the payload cannot hold, before anything is read: each
/// property takes at least a digit and a separator (ASCII), or its scalar's or list length's
/// bytes (binary).
fn check_counts(header: &Header, payload: usize) -> Result<(), IngestError> {
    let mut needed = 0usize;
    for element in header.elements.values() {
        let each = match header.encoding {
            Encoding::Ascii => 2 * element.properties.len(),
            _ => element.properties.values().map(|p| min_bytes(&p.data_type)).sum(),
        };
        if element.count > 0 && each == 0 {
            return Err(IngestError::malformed(
                FORMAT,
                format!(
                    "element '{}' declares {} items but no properties",
                    element.name, element.count
                ),
            ));
        }
        needed = needed.saturating_add(element.count.saturating_mul(each));
    }
    let vertex = header.elements.get("vertex");
    if vertex.is_none_or(|v| !["x", "y", "z"].iter().all(|axis| v.properties.contains_key(*axis))) {
        return Err(IngestError::malformed(FORMAT, "no 'vertex' element with x, y and z"));
    }
    if header.elements.get("face").is_some_and(|f| index_list(f).is_none()) {
        return Err(IngestError::malformed(
            FORMAT,
            "the 'face' element has no vertex_indices list",
        ));
    }
    match needed > payload {
        true => Err(IngestError::malformed(
            FORMAT,
            format!("the header declares at least {needed} bytes of data but the file holds {payload} (truncated?)"),
        )),
        false => Ok(()),
    }
}

fn index_list(face: &ElementDef) -> Option<&str> {
    INDEX_LISTS.into_iter().find(|name| {
        face.properties
            .get(*name)
            .is_some_and(|p| matches!(p.data_type, PropertyType::List(..)))
    })
}

/// The fewest bytes a binary property takes: a scalar's size, or a list's length alone.
fn min_bytes(data_type: &PropertyType) -> usize {
    use ply_rs_bw::ply::ScalarType::*;
    let size = |scalar: &ply_rs_bw::ply::ScalarType| match scalar {
        Char | UChar => 1,
        Short | UShort => 2,
        Int | UInt | Float => 4,
        Double => 8,
    };
    match data_type {
        PropertyType::Scalar(scalar) | PropertyType::List(scalar, _) => size(scalar),
    }
}

fn as_f64(property: &Property) -> Option<f64> {
    Some(match *property {
        Property::Char(v) => v.into(),
        Property::UChar(v) => v.into(),
        Property::Short(v) => v.into(),
        Property::UShort(v) => v.into(),
        Property::Int(v) => v.into(),
        Property::UInt(v) => v.into(),
        Property::Float(v) => v.into(),
        Property::Double(v) => v,
        _ => return None,
    })
}

/// A vertex's position.
#[derive(Default)]
struct Vertex(glam::DVec3);

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return PropertyAccessResult::Ignored,
        };
        match as_f64(&property) {
            Some(value) => {
                self.0[axis] = value;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

/// A face's corners; a negative index stays negative, to be refused as out of range.
#[derive(Default)]
struct Face(Vec<i64>);

impl PropertyAccess for Face {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if !INDEX_LISTS.contains(&name) {
            return PropertyAccessResult::Ignored;
        }
        self.0 = match property {
            Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// An element that is read past.
struct Skipped;

impl PropertyAccess for Skipped {
    fn new() -> Self {
        Skipped
    }
}
