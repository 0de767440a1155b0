//! Compute shaders compiled to SPIR-V whose float arithmetic is marked `NoContraction`.
//!
//! Without the mark a Vulkan driver may fuse `a * b + c` into one rounding, and hardware
//! drivers do: on an NVIDIA H100, parity voxels and the eval's depth images then differed from
//! their CPU twins, which round every operation as Rust does. naga emits no such mark from WGSL,
//! so the WGSL goes through naga here, every float operation gets the decoration, and the
//! entry point reaches the driver as SPIR-V (wgpu's passthrough), with its bindings laid out
//! from naga's reflection.

use naga::back::spv;
use naga::valid::{Capabilities, ValidationFlags, Validator};

/// One compute entry point of a WGSL source as SPIR-V, and the layout of what it binds.
pub(crate) struct PreciseEntry {
    pub words: Vec<u32>,
    pub workgroup_size: [u32; 3],
    /// Its group-0 buffers, by binding number, as wgpu's automatic layout would give them.
    pub bindings: Vec<wgpu::BindGroupLayoutEntry>,
}

impl PreciseEntry {
    /// Compiles `entry` of `source`; `Ok(None)` where it binds something other than buffers or
    /// is not there, and an error naming what naga refused.
    pub fn compile(source: &str, entry: &str) -> Result<Option<PreciseEntry>, String> {
        let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
        let info = Validator::new(ValidationFlags::all(), Capabilities::empty())
            .validate(&module)
            .map_err(|e| e.emit_to_string(source))?;
        let Some(index) = module.entry_points.iter().position(|e| e.name == entry) else {
            return Ok(None);
        };
        let uses = info.get_entry_point(index);
        let mut bindings = Vec::new();
        for (handle, global) in module.global_variables.iter() {
            let Some(binding) = global.binding.as_ref().filter(|b| b.group == 0) else {
                continue;
            };
            if uses[handle].is_empty() {
                continue;
            }
            let ty = match global.space {
                naga::AddressSpace::Storage { access } => wgpu::BufferBindingType::Storage {
                    read_only: !access.contains(naga::StorageAccess::STORE),
                },
                naga::AddressSpace::Uniform => wgpu::BufferBindingType::Uniform,
                _ => return Ok(None),
            };
            bindings.push(wgpu::BindGroupLayoutEntry {
                binding: binding.binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            });
        }
        bindings.sort_by_key(|b| b.binding);
        // wgpu's Vulkan layer numbers a layout's bindings 0, 1, 2... in order, and maps a WGSL
        // module's onto them as it compiles it; passthrough SPIR-V must carry those numbers.
        let mut options = options();
        options.binding_map = bindings
            .iter()
            .enumerate()
            .map(|(vulkan, b)| {
                let wgsl = naga::ResourceBinding {
                    group: 0,
                    binding: b.binding,
                };
                let info = spv::BindingInfo {
                    descriptor_set: 0,
                    binding: vulkan as u32,
                    binding_array_size: None,
                };
                (wgsl, info)
            })
            .collect();
        let pipeline = spv::PipelineOptions {
            shader_stage: naga::ShaderStage::Compute,
            entry_point: entry.into(),
        };
        let mut words = spv::write_vec(&module, &info, &options, Some(&pipeline)).map_err(|e| e.to_string())?;
        mark_no_contraction(&mut words);
        Ok(Some(PreciseEntry {
            words,
            workgroup_size: module.entry_points[index].workgroup_size,
            bindings,
        }))
    }
}

/// naga's SPIR-V settings, those wgpu gives a WGSL module on a driver with robust buffer
/// access 2 (lavapipe's and NVIDIA's): buffer accesses left to the driver, which drops writes
/// past a binding and reads zero there (naga's own check cannot guard atomics); array indices
/// clamped.
fn options() -> spv::Options<'static> {
    use naga::proc::BoundsCheckPolicy::{Restrict, Unchecked};
    spv::Options {
        flags: spv::WriterFlags::empty(),
        bounds_check_policies: naga::proc::BoundsCheckPolicies {
            index: Restrict,
            buffer: Unchecked,
            image_load: Restrict,
            binding_array: Restrict,
        },
        ..Default::default()
    }
}

/// SPIR-V opcodes of float arithmetic a driver could contract.
const FLOAT_ARITHMETIC: [u32; 13] = [
    127, // OpFNegate
    129, // OpFAdd
    131, // OpFSub
    133, // OpFMul
    136, // OpFDiv
    140, // OpFRem
    141, // OpFMod
    142, // OpVectorTimesScalar
    143, // OpMatrixTimesScalar
    144, // OpVectorTimesMatrix
    145, // OpMatrixTimesVector
    146, // OpMatrixTimesMatrix
    148, // OpDot
];
const OP_DECORATE: u32 = 71;
const NO_CONTRACTION: u32 = 42;
/// OpTypeVoid to OpTypeForwardPointer: the first of them ends the annotations.
const TYPE_DECLARATIONS: std::ops::RangeInclusive<u32> = 19..=39;
/// SPIR-V's header: magic, version, generator, bound, schema.
const HEADER_WORDS: usize = 5;

/// The instructions of a SPIR-V module after its header: (offset, opcode, words).
fn instructions(words: &[u32]) -> impl Iterator<Item = (usize, u32, &[u32])> {
    let mut at = HEADER_WORDS;
    std::iter::from_fn(move || {
        let first = *words.get(at)?;
        let count = ((first >> 16) as usize).max(1);
        let instruction = words.get(at..at + count)?;
        let item = (at, first & 0xffff, instruction);
        at += count;
        Some(item)
    })
}

/// Decorates the result of every float arithmetic instruction with `NoContraction`, at the end
/// of the module's annotations.
fn mark_no_contraction(words: &mut Vec<u32>) {
    let results: Vec<u32> = instructions(words)
        .filter(|(_, op, w)| FLOAT_ARITHMETIC.contains(op) && w.len() > 2)
        .map(|(_, _, w)| w[2])
        .collect();
    let types = instructions(words).find(|(_, op, _)| TYPE_DECLARATIONS.contains(op));
    // Float arithmetic needs a float type, so `results` is empty where there is none.
    let at = types.map_or(words.len(), |(at, _, _)| at);
    let decorations = results
        .iter()
        .flat_map(|&id| [(3 << 16) | OP_DECORATE, id, NO_CONTRACTION]);
    words.splice(at..at, decorations);
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHADER: &str = "
        @group(0) @binding(0) var<storage, read> input: array<f32>;
        @group(0) @binding(3) var<storage, read_write> output: array<f32>;
        @group(0) @binding(2) var<storage, read_write> unused: array<u32>;
        @compute @workgroup_size(64)
        fn main(@builtin(global_invocation_id) id: vec3<u32>) {
            let a = vec2<f32>(input[0], input[1]);
            output[id.x] = input[2] * input[3] - input[4] * input[5] + dot(a, a) / input[6];
        }
        @compute @workgroup_size(32)
        fn other() {
            unused[0] = 1u;
        }";

    /// The (opcode, words) of each instruction.
    fn ops(words: &[u32]) -> Vec<(u32, Vec<u32>)> {
        instructions(words).map(|(_, op, w)| (op, w.to_vec())).collect()
    }

    #[test]
    fn every_float_operation_is_marked_before_the_first_type() {
        let compiled = PreciseEntry::compile(SHADER, "main").unwrap().unwrap();
        let ops = ops(&compiled.words);
        let arithmetic: Vec<u32> = ops
            .iter()
            .filter(|(op, _)| FLOAT_ARITHMETIC.contains(op))
            .map(|(_, w)| w[2])
            .collect();
        let is_mark = |(op, w): &(u32, Vec<u32>)| *op == OP_DECORATE && w[2] == NO_CONTRACTION;
        let marked: Vec<u32> = ops.iter().filter(|o| is_mark(o)).map(|(_, w)| w[1]).collect();
        // Two products, a difference, a dot product, a quotient and a sum.
        assert!(arithmetic.len() >= 6, "{arithmetic:?}");
        assert_eq!(marked, arithmetic);
        let first_type = ops.iter().position(|(op, _)| TYPE_DECLARATIONS.contains(op)).unwrap();
        assert!(ops.iter().rposition(is_mark).unwrap() < first_type);
        // The instructions walk to the end of the module exactly.
        let (last, _, w) = instructions(&compiled.words).last().unwrap();
        assert_eq!(last + w.len(), compiled.words.len());
    }

    #[test]
    fn bindings_are_those_the_entry_uses_numbered_as_wgpu_numbers_them() {
        let compiled = PreciseEntry::compile(SHADER, "main").unwrap().unwrap();
        let read_only: Vec<(u32, bool)> = compiled
            .bindings
            .iter()
            .map(|b| match b.ty {
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only },
                    ..
                } => (b.binding, read_only),
                _ => panic!("{b:?}"),
            })
            .collect();
        assert_eq!(read_only, [(0, true), (3, false)]);
        assert_eq!(compiled.workgroup_size, [64, 1, 1]);
        // WGSL's bindings 0 and 3 are Vulkan's 0 and 1.
        const BINDING: u32 = 33;
        let ops = ops(&compiled.words);
        let mut numbers: Vec<u32> = ops
            .iter()
            .filter(|(op, w)| *op == OP_DECORATE && w[2] == BINDING)
            .map(|(_, w)| w[3])
            .collect();
        numbers.sort();
        assert_eq!(numbers, [0, 1]);
        assert!(PreciseEntry::compile(SHADER, "absent").unwrap().is_none());
        assert!(PreciseEntry::compile("fn broken(", "main").is_err());
    }
}
