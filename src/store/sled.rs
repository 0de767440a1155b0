//! The embedded store: one sled database with a tree per kind of record, and the work queue in
//! memory, rebuilt on open from the jobs a previous run left unfinished.

use super::job::{Job, JobState, now_ms};
use super::{Claim, Delivery, Input, ResultMeta, Store, StoreError, StoreResult, Unwritten, seal, unseal};
use async_trait::async_trait;
use std::collections::{HashMap, VecDeque};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

pub struct SledStore {
    db: sled::Db,
    jobs: sled::Tree,
    inputs: sled::Tree,
    glbs: sled::Tree,
    reports: sled::Tree,
    metas: sled::Tree,
    previews: sled::Tree,
    queue: Arc<Queue>,
}

/// The jobs waiting for a worker, in one lane per owner; the key of each job queued or running,
/// by key; and the jobs queued or in a worker's hands.
#[derive(Default)]
struct Queue {
    lanes: Mutex<Lanes>,
    ready: tokio::sync::Notify,
    claims: Mutex<HashMap<String, Claim>>,
}

/// Waiting job ids by owner, each with the times it was handed out before. Workers take from
/// the owners in turn, so that one owner's burst does not hold back another's job.
#[derive(Default)]
struct Lanes {
    waiting: HashMap<Option<String>, VecDeque<(String, u32)>>,
    /// Owners with waiting jobs, the next to be served first.
    turns: VecDeque<Option<String>>,
    /// Jobs queued or in a worker's hands, by owner.
    unfinished: HashMap<Option<String>, usize>,
}

impl Queue {
    fn push(&self, id: String, owner: Option<String>, delivered_before: u32) {
        let mut lanes = self.lanes.lock().unwrap();
        *lanes.unfinished.entry(owner.clone()).or_default() += 1;
        let lane = lanes.waiting.entry(owner.clone()).or_default();
        lane.push_back((id, delivered_before));
        if lane.len() == 1 {
            lanes.turns.push_back(owner);
        }
        drop(lanes);
        self.ready.notify_one();
    }

    /// The next owner's oldest waiting job.
    fn pop(&self) -> Option<(String, Option<String>, u32)> {
        let mut lanes = self.lanes.lock().unwrap();
        let owner = lanes.turns.pop_front()?;
        let lane = lanes.waiting.get_mut(&owner).expect("an owner in turn has a lane");
        let (id, before) = lane.pop_front().expect("an owner in turn has a waiting job");
        if lane.is_empty() {
            lanes.waiting.remove(&owner);
        } else {
            lanes.turns.push_back(owner.clone());
        }
        Some((id, owner, before))
    }

    fn finish(&self, owner: &Option<String>) {
        let mut lanes = self.lanes.lock().unwrap();
        if let Some(count) = lanes.unfinished.get_mut(owner) {
            *count -= 1;
            if *count == 0 {
                lanes.unfinished.remove(owner);
            }
        }
    }
}

struct SledDelivery {
    id: String,
    owner: Option<String>,
    deliveries: u32,
    queue: Arc<Queue>,
}

#[async_trait]
impl Delivery for SledDelivery {
    fn job_id(&self) -> &str {
        &self.id
    }

    fn deliveries(&self) -> u32 {
        self.deliveries
    }

    /// A job in this process's hands stays there until it finishes or the process ends.
    async fn keep_alive(&self) -> StoreResult<()> {
        Ok(())
    }

    async fn finish(&self) -> StoreResult<()> {
        self.queue.finish(&self.owner);
        Ok(())
    }
}

fn backend(e: impl std::fmt::Display) -> StoreError {
    StoreError::Backend(e.to_string())
}

impl SledStore {
    /// Opens (or makes) the database in `dir`, keeping at most `cache_bytes` of it in memory.
    pub fn open(dir: &Path, cache_bytes: u64) -> StoreResult<SledStore> {
        let db = sled::Config::default()
            .path(dir)
            .cache_capacity(cache_bytes)
            .open()
            .map_err(|e| StoreError::Backend(format!("cannot open {}: {e}", dir.display())))?;
        let tree = |name: &str| db.open_tree(name).map_err(backend);
        let store = SledStore {
            jobs: tree("jobs")?,
            inputs: tree("inputs")?,
            glbs: tree("glbs")?,
            reports: tree("reports")?,
            metas: tree("result_meta")?,
            previews: tree("previews")?,
            db,
            queue: Arc::default(),
        };
        store.queue_unfinished()?;
        Ok(store)
    }

    /// Queues again, oldest first, the jobs that a previous run (a crash, a kill -9) left queued
    /// or running.
    fn queue_unfinished(&self) -> StoreResult<()> {
        let mut unfinished: Vec<Job> = self
            .all_jobs()?
            .into_iter()
            .filter(|j| !j.state.is_finished())
            .collect();
        unfinished.sort_by_key(|j| j.created_ms);
        for mut job in unfinished {
            tracing::info!(job = job.id, key = job.key, "queueing again a job left unfinished");
            job.state = JobState::Queued;
            job.updated_ms = now_ms();
            let bytes = serde_json::to_vec(&job).expect("jobs serialize");
            self.jobs.insert(job.id.as_bytes(), bytes).map_err(backend)?;
            let claim = Claim {
                job: job.id.clone(),
                since_ms: job.created_ms,
            };
            self.queue.claims.lock().unwrap().insert(job.key.clone(), claim);
            self.queue.push(job.id, job.owner, job.attempts);
        }
        self.db.flush().map_err(backend)?;
        Ok(())
    }

    /// Every job record.
    fn all_jobs(&self) -> StoreResult<Vec<Job>> {
        self.jobs
            .iter()
            .map(|entry| decode(&entry.map_err(backend)?.1))
            .collect()
    }

    /// Makes every write so far durable. sled 0.34's `flush_async` can deadlock when called
    /// concurrently (spacejam/sled#1308), so the blocking flush runs on the blocking pool.
    async fn durable(&self) -> StoreResult<()> {
        let db = self.db.clone();
        tokio::task::spawn_blocking(move || db.flush())
            .await
            .map_err(backend)?
            .map_err(backend)?;
        Ok(())
    }

    /// The sealed blob under `key` in `tree`; a broken seal deletes it and reads as missing.
    fn sealed(&self, tree: &sled::Tree, key: &str) -> StoreResult<Option<Vec<u8>>> {
        let Some(value) = tree.get(key).map_err(backend)? else {
            return Ok(None);
        };
        match unseal(&value) {
            Some(payload) => Ok(Some(payload.to_vec())),
            None => {
                tracing::warn!(key, tree = ?String::from_utf8_lossy(&tree.name()), "blob failed its BLAKE3 check; deleted");
                metrics::counter!("occluder_corrupt_blobs_total").increment(1);
                tree.remove(key).map_err(backend)?;
                Ok(None)
            }
        }
    }
}

fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> StoreResult<T> {
    serde_json::from_slice(bytes).map_err(|e| StoreError::Decode(e.to_string()))
}

#[async_trait]
impl Store for SledStore {
    async fn put_job(&self, job: &Job) -> StoreResult<()> {
        let bytes = serde_json::to_vec(job).expect("jobs serialize");
        self.jobs.insert(job.id.as_bytes(), bytes).map_err(backend)?;
        self.durable().await?;
        Ok(())
    }

    async fn put_job_unless_ended(&self, job: &Job) -> StoreResult<Result<(), Unwritten>> {
        let bytes = serde_json::to_vec(job).expect("jobs serialize");
        loop {
            let Some(stored) = self.jobs.get(&job.id).map_err(backend)? else {
                return Ok(Err(Unwritten::Gone));
            };
            let record: Job = decode(&stored)?;
            if record.state.is_finished() {
                return Ok(Err(Unwritten::Ended(Box::new(record))));
            }
            let swapped = self
                .jobs
                .compare_and_swap(&job.id, Some(stored), Some(bytes.as_slice()))
                .map_err(backend)?;
            if swapped.is_ok() {
                self.durable().await?;
                return Ok(Ok(()));
            }
        }
    }

    async fn job(&self, id: &str) -> StoreResult<Option<Job>> {
        self.jobs.get(id).map_err(backend)?.map(|v| decode(&v)).transpose()
    }

    async fn jobs(&self) -> StoreResult<Vec<Job>> {
        self.all_jobs()
    }

    async fn newest_jobs(&self, limit: usize) -> StoreResult<Vec<Job>> {
        self.jobs
            .iter()
            .rev()
            .take(limit)
            .map(|entry| decode(&entry.map_err(backend)?.1))
            .collect()
    }

    async fn delete_job(&self, id: &str) -> StoreResult<()> {
        self.jobs.remove(id).map_err(backend)?;
        Ok(())
    }

    async fn claim(&self, key: &str, id: &str) -> StoreResult<Option<Claim>> {
        let mut claims = self.queue.claims.lock().unwrap();
        if let Some(holder) = claims.get(key) {
            return Ok(Some(holder.clone()));
        }
        let claim = Claim {
            job: id.to_string(),
            since_ms: now_ms(),
        };
        claims.insert(key.to_string(), claim);
        Ok(None)
    }

    async fn release(&self, key: &str, id: &str) -> StoreResult<()> {
        let mut claims = self.queue.claims.lock().unwrap();
        if claims.get(key).is_some_and(|holder| holder.job == id) {
            claims.remove(key);
        }
        Ok(())
    }

    async fn enqueue(&self, job: &Job) -> StoreResult<()> {
        self.queue.push(job.id.clone(), job.owner.clone(), 0);
        Ok(())
    }

    async fn next_job(&self, wait: Duration) -> StoreResult<Option<Box<dyn Delivery>>> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            if let Some((id, owner, before)) = self.queue.pop() {
                return Ok(Some(Box::new(SledDelivery {
                    id,
                    owner,
                    deliveries: before + 1,
                    queue: Arc::clone(&self.queue),
                })));
            }
            if tokio::time::timeout_at(deadline, self.queue.ready.notified())
                .await
                .is_err()
            {
                return Ok(None);
            }
        }
    }

    async fn queue_depth(&self) -> StoreResult<usize> {
        Ok(self.queue.lanes.lock().unwrap().unfinished.values().sum())
    }

    async fn queued_for(&self, owner: Option<&str>) -> StoreResult<usize> {
        let lanes = self.queue.lanes.lock().unwrap();
        Ok(lanes.unfinished.get(&owner.map(str::to_string)).copied().unwrap_or(0))
    }

    async fn put_input(&self, key: &str, input: &Input) -> StoreResult<()> {
        self.inputs.insert(key, seal(&input.encode())).map_err(backend)?;
        Ok(())
    }

    async fn input(&self, key: &str) -> StoreResult<Option<Input>> {
        let payload = self.sealed(&self.inputs, key)?;
        payload
            .map(|p| Input::decode(&p).ok_or_else(|| StoreError::Decode(format!("input {key}"))))
            .transpose()
    }

    async fn delete_input(&self, key: &str) -> StoreResult<()> {
        self.inputs.remove(key).map_err(backend)?;
        Ok(())
    }

    async fn put_result(&self, key: &str, glb: &[u8], report: &[u8], meta: &ResultMeta) -> StoreResult<()> {
        self.glbs.insert(key, seal(glb)).map_err(backend)?;
        self.reports.insert(key, seal(report)).map_err(backend)?;
        self.metas
            .insert(key, serde_json::to_vec(meta).expect("metas serialize"))
            .map_err(backend)?;
        self.durable().await?;
        Ok(())
    }

    async fn result_glb(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.sealed(&self.glbs, key)
    }

    async fn result_report(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.sealed(&self.reports, key)
    }

    async fn result_meta(&self, key: &str) -> StoreResult<Option<ResultMeta>> {
        self.metas.get(key).map_err(backend)?.map(|v| decode(&v)).transpose()
    }

    async fn put_preview(&self, key: &str, png: &[u8]) -> StoreResult<()> {
        self.previews.insert(key, seal(png)).map_err(backend)?;
        Ok(())
    }

    async fn preview(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.sealed(&self.previews, key)
    }

    async fn delete_result(&self, key: &str) -> StoreResult<()> {
        for tree in [&self.glbs, &self.reports, &self.metas, &self.previews] {
            tree.remove(key).map_err(backend)?;
        }
        Ok(())
    }

    async fn results(&self) -> StoreResult<Vec<(String, ResultMeta)>> {
        let mut out = Vec::new();
        for entry in self.metas.iter() {
            let (key, value) = entry.map_err(backend)?;
            out.push((String::from_utf8_lossy(&key).into_owned(), decode(&value)?));
        }
        Ok(out)
    }

    async fn flush(&self) -> StoreResult<()> {
        self.durable().await?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::job::{JobError, JobKind};

    #[tokio::test]
    async fn a_job_ended_meanwhile_keeps_its_end() {
        let dir = std::env::temp_dir().join(format!("occluder-cook-sled-ended-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let store = SledStore::open(&dir, 1 << 20).unwrap();
        let mut job = Job::queued(JobKind::Mesh, "key", serde_json::Value::Null, None);
        // Not stored: not written.
        assert_eq!(store.put_job_unless_ended(&job).await.unwrap(), Err(Unwritten::Gone));
        assert_eq!(store.job(&job.id).await.unwrap(), None);
        store.put_job(&job).await.unwrap();
        job.state = JobState::Running;
        assert_eq!(store.put_job_unless_ended(&job).await.unwrap(), Ok(()));
        assert_eq!(store.job(&job.id).await.unwrap(), Some(job.clone()));
        // Cancelled meanwhile: a later write of its progress or end leaves the cancel.
        let mut cancelled = job.clone();
        cancelled.state = JobState::Failed;
        cancelled.error = Some(JobError {
            code: "cancelled".into(),
            message: "cancelled".into(),
        });
        store.put_job(&cancelled).await.unwrap();
        job.state = JobState::Done;
        assert_eq!(
            store.put_job_unless_ended(&job).await.unwrap(),
            Err(Unwritten::Ended(Box::new(cancelled.clone())))
        );
        assert_eq!(store.job(&job.id).await.unwrap(), Some(cancelled));
        drop(store);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
