//! glTF's EXT_meshopt_compression: the buffer views that positions and indices read, stored
//! compressed by meshoptimizer, are decoded into one new buffer, and the document is pointed at
//! it before any accessor reads them.

use super::{IngestError, IngestLimits};
use serde_json::Value;
use std::collections::BTreeSet;
use std::os::raw::{c_int, c_uchar, c_void};

pub const EXTENSION: &str = "EXT_meshopt_compression";
const FORMAT: &str = "glTF";
/// The codecs reach about 1,000:1 on runs of zeros: a view that declares more decoded bytes than
/// this many times its encoded ones (plus a block) is refused before anything is allocated.
const MAX_RATIO: u64 = 1100;
const SLACK_BYTES: u64 = 4096;

/// Whether a buffer only stands in for compressed views: it has no bytes of its own.
pub fn is_fallback(buffer: &gltf::Buffer) -> bool {
    buffer
        .extension_value(EXTENSION)
        .and_then(|e| e.get("fallback"))
        .and_then(Value::as_bool)
        == Some(true)
}

/// Decodes the compressed views that positions and indices read, appends their bytes to
/// `buffers` as one buffer, and returns the document with those views pointing into it.
pub fn decode(
    document: gltf::Document,
    buffers: &mut Vec<Vec<u8>>,
    limits: &IngestLimits,
) -> Result<gltf::Document, IngestError> {
    let read: BTreeSet<usize> = document
        .meshes()
        .flat_map(|mesh| mesh.primitives().collect::<Vec<_>>())
        .flat_map(|p| [p.get(&gltf::Semantic::Positions), p.indices()])
        .flatten()
        .filter_map(|accessor| Some(accessor.view()?.index()))
        .collect();
    let mut packed = Vec::new();
    let mut moved = Vec::new();
    for view in document.views().filter(|v| read.contains(&v.index())) {
        let Some(stream) = Stream::of(&view)? else { continue };
        let bytes = stream.decode(buffers, limits, view.index())?;
        if bytes.len() != view.length() {
            return Err(malformed(format!(
                "bufferView {} decodes to {} bytes but holds {}",
                view.index(),
                bytes.len(),
                view.length()
            )));
        }
        moved.push((view.index(), packed.len()));
        packed.extend_from_slice(&bytes);
        packed.resize(packed.len().next_multiple_of(4), 0);
    }
    let Some(&(first, _)) = moved.first() else {
        return Ok(document);
    };
    let mut root = document.into_json();
    let mut buffer = root.buffers[root.buffer_views[first].buffer.value()].clone();
    buffer.uri = None;
    buffer.extensions = None;
    buffer.byte_length = packed.len().into();
    let index = gltf::json::Index::new(root.buffers.len() as u32);
    root.buffers.push(buffer);
    for (view, offset) in moved {
        let view = &mut root.buffer_views[view];
        view.buffer = index;
        view.byte_offset = Some(offset.into());
        view.extensions = None;
    }
    buffers.push(packed);
    Ok(gltf::Document::from_json_without_validation(root))
}

fn malformed(message: String) -> IngestError {
    IngestError::malformed(FORMAT, message)
}

/// The compressed stream a view declares in its extension.
struct Stream {
    buffer: usize,
    offset: usize,
    length: usize,
    stride: usize,
    count: usize,
    mode: String,
    filter: String,
}

type Decoder = unsafe extern "C" fn(*mut c_void, usize, usize, *const c_uchar, usize) -> c_int;
type Filter = unsafe extern "C" fn(*mut c_void, usize, usize);

impl Stream {
    fn of(view: &gltf::buffer::View) -> Result<Option<Stream>, IngestError> {
        let Some(extension) = view.extension_value(EXTENSION) else {
            return Ok(None);
        };
        let number = |key: &str, default: Option<u64>| {
            extension
                .get(key)
                .and_then(Value::as_u64)
                .or(default)
                .and_then(|n| usize::try_from(n).ok())
                .ok_or_else(|| malformed(format!("bufferView {}: {EXTENSION} has no valid {key}", view.index())))
        };
        let text = |key: &str, default: &str| {
            extension
                .get(key)
                .and_then(Value::as_str)
                .unwrap_or(default)
                .to_string()
        };
        Ok(Some(Stream {
            buffer: number("buffer", None)?,
            offset: number("byteOffset", Some(0))?,
            length: number("byteLength", None)?,
            stride: number("byteStride", None)?,
            count: number("count", None)?,
            mode: text("mode", ""),
            filter: text("filter", "NONE"),
        }))
    }

    /// The decoded bytes, `count` × `stride` of them, after the filter.
    fn decode(&self, buffers: &[Vec<u8>], limits: &IngestLimits, view: usize) -> Result<Vec<u8>, IngestError> {
        let encoded = buffers
            .get(self.buffer)
            .and_then(|b| b.get(self.offset..self.offset.checked_add(self.length)?))
            .ok_or_else(|| {
                malformed(format!(
                    "bufferView {view}: its compressed bytes lie outside their buffer"
                ))
            })?;
        let size = (self.count as u64).saturating_mul(self.stride as u64);
        limits.check_bytes(size, &format!("decoding bufferView {view}"))?;
        if self.count as u64 > limits.max_unbacked_items() || size > MAX_RATIO * encoded.len() as u64 + SLACK_BYTES {
            return Err(IngestError::TooLarge(format!(
                "bufferView {view}: {} items of {} bytes from {} compressed bytes is more than the codec gives",
                self.count,
                self.stride,
                encoded.len()
            )));
        }
        let decoder: Decoder = match (self.mode.as_str(), self.stride) {
            ("ATTRIBUTES", 4..=256) if self.stride.is_multiple_of(4) => meshopt::ffi::meshopt_decodeVertexBuffer,
            ("TRIANGLES", 2 | 4) if self.count.is_multiple_of(3) => meshopt::ffi::meshopt_decodeIndexBuffer,
            ("INDICES", 2 | 4) => meshopt::ffi::meshopt_decodeIndexSequence,
            (mode, stride) => {
                return Err(malformed(format!(
                    "bufferView {view}: {EXTENSION} mode `{mode}` with byteStride {stride} is not valid"
                )));
            }
        };
        let filter: Option<Filter> = match (self.mode.as_str(), self.filter.as_str(), self.stride) {
            (_, "NONE", _) => None,
            ("ATTRIBUTES", "OCTAHEDRAL", 4 | 8) => Some(meshopt::ffi::meshopt_decodeFilterOct),
            ("ATTRIBUTES", "QUATERNION", 8) => Some(meshopt::ffi::meshopt_decodeFilterQuat),
            ("ATTRIBUTES", "EXPONENTIAL", _) => Some(meshopt::ffi::meshopt_decodeFilterExp),
            ("ATTRIBUTES", "COLOR", 4 | 8) => Some(meshopt::ffi::meshopt_decodeFilterColor),
            (_, filter, stride) => {
                return Err(malformed(format!(
                    "bufferView {view}: {EXTENSION} filter `{filter}` with byteStride {stride} is not valid"
                )));
            }
        };
        let mut decoded = vec![0u8; size as usize];
        // SAFETY: `decoded` holds count × stride bytes, all that the decoder writes, and it reads
        // `encoded` within its length; meshoptimizer's decoders are made for untrusted input.
        let code = unsafe {
            decoder(
                decoded.as_mut_ptr().cast(),
                self.count,
                self.stride,
                encoded.as_ptr(),
                encoded.len(),
            )
        };
        if code != 0 {
            return Err(malformed(format!(
                "bufferView {view}: its {EXTENSION} data does not decode (error {code})"
            )));
        }
        if let Some(filter) = filter {
            // SAFETY: the filter rewrites count items of stride bytes in place, as `decoded` holds,
            // for the strides its match arm allows.
            unsafe { filter(decoded.as_mut_ptr().cast(), self.count, self.stride) };
        }
        Ok(decoded)
    }
}
