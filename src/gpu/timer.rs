//! The device's own time for the passes of one cook, from timestamp queries written at the start
//! and end of every pass (where the adapter has them). Wall-clock stage times include uploads,
//! read-backs and waits; this is the time the GPU itself spent.

use super::{Gpu, GpuError};
use std::sync::Mutex;

/// Query sets grow one at a time as passes are recorded, so no pass goes untimed.
pub(crate) struct PassTimer {
    /// Each set and how many of its queries are written.
    sets: Mutex<Vec<(wgpu::QuerySet, u32)>>,
}

/// Where one pass writes its start and end times.
pub(crate) struct PassStamp {
    set: wgpu::QuerySet,
    begin: u32,
}

impl PassStamp {
    pub fn compute(&self) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(self.begin),
            end_of_pass_write_index: Some(self.begin + 1),
        }
    }

    pub fn render(&self) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(self.begin),
            end_of_pass_write_index: Some(self.begin + 1),
        }
    }
}

impl PassTimer {
    pub fn new() -> PassTimer {
        PassTimer {
            sets: Mutex::new(Vec::new()),
        }
    }

    pub fn stamp(&self, device: &wgpu::Device) -> PassStamp {
        let mut sets = self.sets.lock().unwrap_or_else(|e| e.into_inner());
        if sets.last().is_none_or(|(_, used)| *used == wgpu::QUERY_SET_MAX_QUERIES) {
            let set = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass times"),
                ty: wgpu::QueryType::Timestamp,
                count: wgpu::QUERY_SET_MAX_QUERIES,
            });
            sets.push((set, 0));
        }
        let (set, used) = sets.last_mut().expect("a set was just made");
        *used += 2;
        PassStamp {
            set: set.clone(),
            begin: *used - 2,
        }
    }

    /// The milliseconds the passes stamped since the last call took on the device, summed; the
    /// passes must have been submitted.
    pub fn take_ms(&self, gpu: &Gpu) -> Result<f64, GpuError> {
        let sets = std::mem::take(&mut *self.sets.lock().unwrap_or_else(|e| e.into_inner()));
        let mut ticks = 0u64;
        for (set, used) in sets.iter().filter(|(_, used)| *used > 0) {
            let bytes = u64::from(*used) * wgpu::QUERY_SIZE as u64;
            let resolved = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pass times"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let staging = gpu.staging(bytes);
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            encoder.resolve_query_set(set, 0..*used, &resolved, 0);
            encoder.copy_buffer_to_buffer(&resolved, 0, &staging, 0, bytes);
            let times: Vec<u64> = gpu.finish_read(encoder, &staging)?;
            ticks += times.chunks(2).map(|pass| pass[1].saturating_sub(pass[0])).sum::<u64>();
        }
        Ok(ticks as f64 * f64::from(gpu.queue.get_timestamp_period()) / 1e6)
    }
}
