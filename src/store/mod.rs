//! Where jobs, uploaded inputs and results are kept, and how jobs reach the workers: one trait,
//! so that the service, its workers and level bakes do not know which storage they run on.
//! [`sled::SledStore`] is the embedded one for a single machine; [`nats::NatsStore`] keeps
//! everything in NATS JetStream, for API and worker nodes spread over many machines.
//!
//! Blobs are stored sealed with their BLAKE3 hash; a blob that fails the check on read is
//! deleted and reported missing, never returned.

pub mod job;
pub mod nats;
pub mod sled;

use async_trait::async_trait;
use job::Job;
use serde::{Deserialize, Serialize};
use std::time::Duration;

pub type StoreResult<T> = Result<T, StoreError>;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("storage: {0}")]
    Backend(String),
    #[error("stored record is unreadable: {0}")]
    Decode(String),
}

/// An uploaded mesh, kept until its result exists.
#[derive(Clone, Debug, PartialEq)]
pub struct Input {
    /// `gltf`, `obj` or `stl`.
    pub format: String,
    pub bytes: Vec<u8>,
}

impl Input {
    /// `format length ‖ format ‖ bytes`.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(1 + self.format.len() + self.bytes.len());
        out.push(self.format.len() as u8);
        out.extend_from_slice(self.format.as_bytes());
        out.extend_from_slice(&self.bytes);
        out
    }

    /// Parses the mesh. External glTF buffers cannot be resolved: uploads are self-contained.
    pub fn load(
        &self,
        limits: &crate::mesh::IngestLimits,
    ) -> Result<(crate::mesh::Mesh, crate::mesh::IngestStats), crate::mesh::IngestError> {
        let format = crate::mesh::Format::from_name(&self.format)
            .ok_or_else(|| crate::mesh::IngestError::UnknownFormat(format!("an input filed as `{}`", self.format)))?;
        crate::mesh::load_bytes(&self.bytes, format, None, limits)
    }

    pub fn decode(encoded: &[u8]) -> Option<Input> {
        let (&n, rest) = encoded.split_first()?;
        let (format, bytes) = rest.split_at_checked(n as usize)?;
        Some(Input {
            format: String::from_utf8(format.to_vec()).ok()?,
            bytes: bytes.to_vec(),
        })
    }
}

/// What a finished cook leaves behind, filed under its key.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ResultMeta {
    /// The job that made it.
    pub job: String,
    /// Bytes of the GLB, the report and the input kept beside them, together.
    pub bytes: u64,
    pub created_ms: u64,
}

/// Which job holds a key, and since when (ms since the Unix epoch). The holder's record is
/// written just after its claim, so a claim may briefly name a job not stored yet.
#[derive(Clone, Debug, PartialEq)]
pub struct Claim {
    pub job: String,
    pub since_ms: u64,
}

impl Claim {
    /// `job since_ms`, as a store keeps it.
    pub fn encode(&self) -> String {
        format!("{} {}", self.job, self.since_ms)
    }

    pub fn decode(text: &str) -> Option<Claim> {
        let (job, since) = text.split_once(' ')?;
        Some(Claim {
            job: job.to_string(),
            since_ms: since.parse().ok()?,
        })
    }
}

/// Why [`Store::put_job_unless_ended`] left a job's record as it was.
#[derive(Debug, PartialEq)]
pub enum Unwritten {
    /// The job has ended: its record.
    Ended(Box<Job>),
    /// Its record is gone: it ended, and was collected.
    Gone,
}

/// A job handed to a worker. Until [`Delivery::finish`] the queue may hand it out again: after
/// a restart (sled), or once its worker stops keeping it alive (NATS).
#[async_trait]
pub trait Delivery: Send + Sync {
    fn job_id(&self) -> &str;
    /// Times the queue has handed this job out, this time included.
    fn deliveries(&self) -> u32;
    /// Tells the queue that the job is still being worked on.
    async fn keep_alive(&self) -> StoreResult<()>;
    /// Takes the job off the queue for good.
    async fn finish(&self) -> StoreResult<()>;
}

#[async_trait]
pub trait Store: Send + Sync + 'static {
    /// Writes a job record and makes it durable before returning.
    async fn put_job(&self, job: &Job) -> StoreResult<()>;
    /// Writes over the record of a job that others may end meanwhile (a cancel through any
    /// node, or a worker that had it before), in one step with the check that they have not:
    /// where the stored record has ended, or is gone, it stays. Durable, as `put_job`.
    async fn put_job_unless_ended(&self, job: &Job) -> StoreResult<Result<(), Unwritten>>;
    /// Writes a running job's progress where other nodes read it, as `put_job_unless_ended`.
    /// The embedded store keeps progress in the process's memory only, and writes nothing.
    async fn put_progress(&self, _job: &Job) -> StoreResult<Result<(), Unwritten>> {
        Ok(Ok(()))
    }
    async fn job(&self, id: &str) -> StoreResult<Option<Job>>;
    /// Every job record: those queued or running, and those ended but not yet collected.
    async fn jobs(&self) -> StoreResult<Vec<Job>>;
    /// The `limit` newest job records, newest first. Ids begin with their creation time in
    /// fixed-width hex, so the newest are the greatest; only those are read.
    async fn newest_jobs(&self, limit: usize) -> StoreResult<Vec<Job>>;
    async fn delete_job(&self, id: &str) -> StoreResult<()>;

    /// Claims `key` for the job `id`, unless a job holds it already: then that claim.
    async fn claim(&self, key: &str, id: &str) -> StoreResult<Option<Claim>>;
    /// Lets go of `key` if the job `id` holds it.
    async fn release(&self, key: &str, id: &str) -> StoreResult<()>;
    /// Puts a stored job on the work queue, in its owner's lane.
    async fn enqueue(&self, job: &Job) -> StoreResult<()>;
    /// The next job for a worker, or None when none came within `wait`. The lanes of the
    /// owners with waiting jobs take turns.
    async fn next_job(&self, wait: Duration) -> StoreResult<Option<Box<dyn Delivery>>>;
    /// Jobs on the queue: waiting, or handed out and not finished.
    async fn queue_depth(&self) -> StoreResult<usize>;
    /// The jobs of `owner` (None: submitted without a token) on the queue.
    async fn queued_for(&self, owner: Option<&str>) -> StoreResult<usize>;

    async fn put_input(&self, key: &str, input: &Input) -> StoreResult<()>;
    async fn input(&self, key: &str) -> StoreResult<Option<Input>>;
    async fn delete_input(&self, key: &str) -> StoreResult<()>;

    /// Stores a result (GLB and report JSON) durably.
    async fn put_result(&self, key: &str, glb: &[u8], report: &[u8], meta: &ResultMeta) -> StoreResult<()>;
    /// The GLB, if present and intact.
    async fn result_glb(&self, key: &str) -> StoreResult<Option<Vec<u8>>>;
    /// The report JSON, if present and intact.
    async fn result_report(&self, key: &str) -> StoreResult<Option<Vec<u8>>>;
    async fn result_meta(&self, key: &str) -> StoreResult<Option<ResultMeta>>;
    /// Files the preview sheet (PNG) drawn for a stored result.
    async fn put_preview(&self, key: &str, png: &[u8]) -> StoreResult<()>;
    /// The preview sheet, if one was drawn and is intact.
    async fn preview(&self, key: &str) -> StoreResult<Option<Vec<u8>>>;
    /// Deletes the result, with its preview.
    async fn delete_result(&self, key: &str) -> StoreResult<()>;
    /// Every stored result: (key, meta).
    async fn results(&self) -> StoreResult<Vec<(String, ResultMeta)>>;

    async fn flush(&self) -> StoreResult<()>;
}

/// How long a store call that fails in its backend is retried: a worker then waits with its job
/// until the store answers, and runs it again.
pub const PATIENCE: Duration = Duration::from_secs(30);

/// Retries a store call about `id` (a job, a key) that failed in its backend (a NATS server
/// restarting, say) for up to [`PATIENCE`], and returns its last answer. A record that cannot be
/// decoded is not retried: it reads the same the next time.
pub async fn patiently<T, F, Fut>(what: &str, id: &str, mut call: F) -> StoreResult<T>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = StoreResult<T>>,
{
    let mut pause = Duration::from_millis(100);
    let started = tokio::time::Instant::now();
    loop {
        match call().await {
            Err(e @ StoreError::Backend(_)) if started.elapsed() < PATIENCE => {
                tracing::warn!(id, error = %e, "cannot {what} yet; retrying");
                tokio::time::sleep(pause).await;
                pause = (pause * 2).min(Duration::from_secs(2));
            }
            Err(e) => {
                tracing::error!(id, error = %e, "cannot {what}");
                return Err(e);
            }
            answer => return answer,
        }
    }
}

/// `hash ‖ payload`.
pub fn seal(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(32 + payload.len());
    out.extend_from_slice(blake3::hash(payload).as_bytes());
    out.extend_from_slice(payload);
    out
}

/// The payload of a sealed blob, if its hash matches.
pub fn unseal(sealed: &[u8]) -> Option<&[u8]> {
    let (hash, payload) = sealed.split_at_checked(32)?;
    (blake3::hash(payload).as_bytes() == hash).then_some(payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A store call that answers `failures` backend errors, then `Ok(calls)`.
    fn failing(failures: usize, calls: &AtomicUsize) -> impl std::future::Future<Output = StoreResult<usize>> {
        let call = calls.fetch_add(1, Ordering::Relaxed) + 1;
        async move {
            match call <= failures {
                true => Err(StoreError::Backend("nats: missed idle heartbeat".into())),
                false => Ok(call),
            }
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_store_call_is_retried_while_its_backend_fails() {
        let calls = AtomicUsize::new(0);
        let answer = patiently("read the input", "job", || failing(3, &calls)).await;
        assert_eq!(answer.unwrap(), 4);
        assert_eq!(calls.load(Ordering::Relaxed), 4);
    }

    #[tokio::test(start_paused = true)]
    async fn a_store_call_gives_up_after_its_patience() {
        let calls = AtomicUsize::new(0);
        let started = tokio::time::Instant::now();
        let answer = patiently("read the input", "job", || failing(usize::MAX, &calls)).await;
        assert!(started.elapsed() >= PATIENCE);
        assert!(calls.load(Ordering::Relaxed) > 2, "not retried");
        assert!(matches!(answer, Err(StoreError::Backend(_))));
    }

    #[tokio::test(start_paused = true)]
    async fn an_unreadable_record_is_not_read_again() {
        let calls = AtomicUsize::new(0);
        let answer: StoreResult<()> = patiently("read the input", "job", || {
            calls.fetch_add(1, Ordering::Relaxed);
            async { Err(StoreError::Decode("truncated".into())) }
        })
        .await;
        assert_eq!(calls.load(Ordering::Relaxed), 1);
        assert!(matches!(answer, Err(StoreError::Decode(_))));
    }

    #[test]
    fn a_flipped_bit_breaks_the_seal() {
        let mut sealed = seal(b"occluder");
        assert_eq!(unseal(&sealed), Some(&b"occluder"[..]));
        sealed[35] ^= 1;
        assert_eq!(unseal(&sealed), None);
        assert_eq!(unseal(b"short"), None);
    }

    #[test]
    fn inputs_round_trip() {
        let input = Input {
            format: "obj".into(),
            bytes: b"v 0 0 0".to_vec(),
        };
        assert_eq!(Input::decode(&input.encode()), Some(input));
    }
}
