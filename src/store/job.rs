//! A cook job: what was asked, and where it stands.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Done,
    Failed,
}

impl JobState {
    pub fn is_finished(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed)
    }

    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
        }
    }
}

/// What a job makes: one mesh's occluder, or a whole level's batches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobKind {
    #[default]
    Mesh,
    Level,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobError {
    pub code: String,
    pub message: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Job {
    pub id: String,
    #[serde(default)]
    pub kind: JobKind,
    /// The content key of the mesh and settings; the result is filed under it.
    pub key: String,
    pub state: JobState,
    /// The pipeline stage running now, or the last one.
    pub stage: Option<String>,
    /// 0 to 1.
    pub progress: f64,
    pub error: Option<JobError>,
    /// The effective settings, as JSON: `cook.*` for a mesh, `{"cook": …, "level": …}` for a level.
    #[schema(value_type = Object)]
    pub settings: serde_json::Value,
    pub created_ms: u64,
    pub updated_ms: u64,
    /// Times a worker has started it (a restart runs unfinished jobs again).
    pub attempts: u32,
    /// The name of the token that filed it, when the service takes tokens: who may cancel it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub owner: Option<String>,
}

impl Job {
    /// A new job, queued now, with a fresh id.
    pub fn queued(kind: JobKind, key: &str, settings: serde_json::Value, owner: Option<String>) -> Job {
        let now = now_ms();
        Job {
            id: new_id(),
            kind,
            key: key.to_string(),
            state: JobState::Queued,
            stage: None,
            progress: 0.0,
            error: None,
            settings,
            created_ms: now,
            updated_ms: now,
            attempts: 0,
            owner,
        }
    }
}

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// A job id: unique across processes and machines.
pub fn new_id() -> String {
    format!("{:012x}{:016x}", now_ms(), fastrand::u64(..))
}

/// Whether `id` has the shape [`new_id`] gives: 28 lowercase hex digits. Anything else names no
/// job, and is never sent to a store (a NATS key cannot hold every character).
pub fn is_id(id: &str) -> bool {
    id.len() == 28 && id.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}
