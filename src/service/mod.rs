//! The cook service: an HTTP API ([`api`]) over a durable job queue, a pool of workers that run
//! the pipeline, and a content-addressed result cache, all kept in a [`store::Store`].
//!
//! A job is durable before its submission is answered, and it stays on the store's queue until a
//! worker finishes it: a crash, a kill -9 or a lost worker node hands it out again. Identical work
//! is never done twice: a submission whose key has a result gets it, and one whose key is claimed
//! by a queued or running job gets that job, across every node that shares the store.

pub mod api;
pub mod auth;
pub mod client;
pub mod dashboard;
pub mod tls;

use crate::config::Settings;
use crate::cook::{CookError, cook_with_progress};
use crate::store::job::{Job, JobError, JobKind, JobState, now_ms};
use crate::store::{self, Delivery, Input, ResultMeta, Store, StoreError, StoreResult, Unwritten, patiently};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;

/// Shared by the API handlers and the workers.
pub struct Service {
    pub store: Arc<dyn Store>,
    /// The server's settings; a job's query parameters override `cook.*` keys.
    pub settings: Settings,
    /// Jobs this process's workers are running, by id, with their latest progress.
    live: Mutex<HashMap<String, Job>>,
    /// Set to stop a running job at its next stage (DELETE), by id.
    stops: Mutex<HashMap<String, std::sync::Weak<std::sync::atomic::AtomicBool>>>,
    cache: Mutex<Lru>,
    /// Keys of uploads seen before, by the BLAKE3 of their bytes, format and settings: a repeat
    /// upload skips parsing.
    seen: Mutex<HashMap<blake3::Hash, String>>,
    /// Worker tasks this process runs (0 on an API-only node).
    workers: std::sync::atomic::AtomicUsize,
}

/// What the service is doing: the figures of /metrics's gauges, as JSON for the dashboard.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Activity {
    /// Jobs waiting to run, over the whole store (every node of a cluster).
    pub queue_depth: usize,
    /// Jobs this node's workers are running.
    pub running: usize,
    /// Worker tasks on this node.
    pub workers: usize,
    /// Bytes of results and kept inputs, and the most kept before eviction.
    pub cache_bytes: u64,
    pub max_cache_bytes: u64,
}

/// What a job made: its GLB and report, and the bytes of the input kept beside them.
struct Made {
    glb: Vec<u8>,
    report: Vec<u8>,
    input_bytes: u64,
}

/// Raised to stop a running job at its next stage.
type Stop = Arc<std::sync::atomic::AtomicBool>;

/// Error codes of jobs stopped on purpose.
const TIMEOUT: &str = "timeout";
const CANCELLED: &str = "cancelled";

/// The input format of a level job: its manifest, every mesh given by key.
pub const LEVEL_FORMAT: &str = "level";

/// A level job's settings.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct LevelJobSettings {
    pub cook: crate::config::CookSettings,
    pub level: crate::config::LevelSettings,
}

/// How long a claim may name a job whose record is not stored before it counts as stale.
const CLAIM_GRACE_MS: u64 = 60_000;

/// Most remembered uploads; the memo starts over beyond it.
const SEEN_UPLOADS: usize = 100_000;

/// Least recently used results, by key: (last access, bytes), with the keys in order of last
/// access so that a victim is found without scanning every entry.
#[derive(Default)]
struct Lru {
    entries: HashMap<String, (u64, u64)>,
    by_use: std::collections::BTreeMap<u64, String>,
    bytes: u64,
    clock: u64,
}

impl Lru {
    fn touch(&mut self, key: &str, bytes: u64) {
        self.clock += 1;
        if let Some((used, old)) = self.entries.insert(key.to_string(), (self.clock, bytes)) {
            self.by_use.remove(&used);
            self.bytes -= old;
        }
        self.by_use.insert(self.clock, key.to_string());
        self.bytes += bytes;
    }

    fn remove(&mut self, key: &str) {
        if let Some((used, bytes)) = self.entries.remove(key) {
            self.by_use.remove(&used);
            self.bytes -= bytes;
        }
    }

    /// The least recently used key that `keep` does not hold on to.
    fn oldest(&self, keep: impl Fn(&str) -> bool) -> Option<String> {
        self.by_use.values().find(|k| !keep(k)).cloned()
    }
}

/// What a submission turned into.
pub enum Submitted {
    /// The result already exists, made by this job.
    Cached(String),
    /// A job is queued or running for it: a new one, or the one that was already there.
    Queued(String),
}

#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    #[error("the queue is full ({0} jobs waiting)")]
    QueueFull(usize),
    #[error("token `{owner}` has {queued} jobs queued or running (service.token_max_queued)")]
    OwnerQueueFull { owner: String, queued: usize },
    #[error(transparent)]
    Store(#[from] StoreError),
}

impl Service {
    /// Opens the service on `store`.
    pub async fn start(store: Arc<dyn Store>, settings: Settings) -> StoreResult<Arc<Service>> {
        let service = Arc::new(Service {
            store,
            settings,
            live: Mutex::new(HashMap::new()),
            stops: Mutex::new(HashMap::new()),
            cache: Mutex::new(Lru::default()),
            seen: Mutex::new(HashMap::new()),
            workers: Default::default(),
        });
        // Oldest first, so that the least recently made is the first to go.
        let mut results = service.store.results().await?;
        results.sort_by_key(|(_, meta)| meta.created_ms);
        for (key, meta) in results {
            service.cache.lock().unwrap().touch(&key, meta.bytes);
        }
        service.update_gauges().await;
        Ok(service)
    }

    /// Files a job for `input` under `key`, unless the result exists (answered with a done job)
    /// or a job holds the key.
    pub async fn submit(
        &self,
        key: &str,
        input: Input,
        settings: serde_json::Value,
        owner: Option<String>,
    ) -> Result<Submitted, SubmitError> {
        let kind = if input.format == LEVEL_FORMAT {
            JobKind::Level
        } else {
            JobKind::Mesh
        };
        let job = Job::queued(kind, key, settings, owner);
        if let Some(meta) = self.result_meta(key).await? {
            metrics::counter!("occluder_cache_hits_total").increment(1);
            return Ok(Submitted::Cached(self.serving(meta, job).await?));
        }
        // Claim the key first, so that an identical submission arriving now, on any node, joins
        // this job. A claim left by a job that has ended (its node died) is taken over.
        while let Some(holder) = self.store.claim(key, &job.id).await? {
            match self.held_job(&holder).await? {
                Some(held) if !held.state.is_finished() => {
                    metrics::counter!("occluder_dedup_joins_total").increment(1);
                    return Ok(Submitted::Queued(holder.job));
                }
                Some(held) if held.state == JobState::Done && self.result_meta(key).await?.is_some() => {
                    return Ok(Submitted::Cached(holder.job));
                }
                _ => self.store.release(key, &holder.job).await?,
            }
        }
        metrics::counter!("occluder_cache_misses_total").increment(1);
        let waiting = self.store.queue_depth().await?;
        if waiting >= self.settings.service.max_queue {
            self.store.release(key, &job.id).await?;
            return Err(SubmitError::QueueFull(waiting));
        }
        if let Some(owner) = &job.owner {
            let queued = self.store.queued_for(Some(owner)).await?;
            metrics::gauge!("occluder_token_queued_jobs", "token" => owner.clone()).set(queued as f64);
            if queued >= self.settings.service.token_max_queued {
                self.store.release(key, &job.id).await?;
                metrics::counter!("occluder_submissions_limited_total", "token" => owner.clone()).increment(1);
                return Err(SubmitError::OwnerQueueFull {
                    owner: owner.clone(),
                    queued,
                });
            }
        }
        let stored = async {
            // The input first: the job's record makes both durable (sled flushes there).
            self.store.put_input(key, &input).await?;
            self.store.put_job(&job).await?;
            self.store.enqueue(&job).await
        }
        .await;
        if let Err(e) = stored {
            // The job never reached the queue: it must not hold the key.
            let mut failed = job.clone();
            failed.state = JobState::Failed;
            failed.error = Some(JobError {
                code: "storage".into(),
                message: e.to_string(),
            });
            let _ = self.store.put_job(&failed).await;
            let _ = self.store.release(key, &job.id).await;
            return Err(e.into());
        }
        // The depth read above, plus this job: no second round trip to the store.
        metrics::gauge!("occluder_queue_depth").set((waiting + 1) as f64);
        Ok(Submitted::Queued(job.id))
    }

    /// The job to answer a submission of a stored result with: the one that made it, unless
    /// that one was cancelled after storing it, or its record is gone. Then `job`, this
    /// submission's, is recorded as done, so that its status says what the result is.
    async fn serving(&self, made: ResultMeta, mut job: Job) -> StoreResult<String> {
        match self.store.job(&made.job).await? {
            Some(maker) if maker.state != JobState::Failed => Ok(made.job),
            maker => {
                tracing::info!(
                    job = job.id,
                    made_by = made.job,
                    maker = maker.map_or("gone", |m| m.state.name()),
                    "a stored result's maker did not end done; this submission is recorded done"
                );
                job.state = JobState::Done;
                job.progress = 1.0;
                self.store.put_job(&job).await?;
                Ok(job.id)
            }
        }
    }

    /// The job that holds a claim. Its record follows the claim within moments: a young claim
    /// whose job is not stored yet is waited for, an old one is stale (its node died between).
    async fn held_job(&self, claim: &store::Claim) -> StoreResult<Option<Job>> {
        loop {
            if let Some(job) = self.store.job(&claim.job).await? {
                return Ok(Some(job));
            }
            if now_ms().saturating_sub(claim.since_ms) > CLAIM_GRACE_MS {
                return Ok(None);
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// The key of an upload seen before.
    pub fn seen_key(&self, upload: &blake3::Hash) -> Option<String> {
        self.seen.lock().unwrap().get(upload).cloned()
    }

    pub fn remember_key(&self, upload: blake3::Hash, key: &str) {
        let mut seen = self.seen.lock().unwrap();
        if seen.len() >= SEEN_UPLOADS {
            seen.clear();
        }
        seen.insert(upload, key.to_string());
    }

    /// The `limit` most recently created jobs, newest first, with the latest progress of those
    /// running here.
    pub async fn recent_jobs(&self, limit: usize) -> StoreResult<Vec<Job>> {
        let mut jobs = self.store.newest_jobs(limit).await?;
        let live = self.live.lock().unwrap();
        for job in &mut jobs {
            if let Some(latest) = live.get(&job.id) {
                *job = latest.clone();
            }
        }
        Ok(jobs)
    }

    /// The job's latest state.
    pub async fn job(&self, id: &str) -> StoreResult<Option<Job>> {
        if let Some(job) = self.live.lock().unwrap().get(id) {
            return Ok(Some(job.clone()));
        }
        self.store.job(id).await
    }

    pub async fn result_meta(&self, key: &str) -> StoreResult<Option<ResultMeta>> {
        self.store.result_meta(key).await
    }

    /// The result's GLB, if it exists and is intact. A broken one is dropped and, where its
    /// input is still kept, cooked again: the id of that job comes back as the error.
    pub async fn result_glb(&self, key: &str) -> StoreResult<Result<Vec<u8>, Option<String>>> {
        match self.store.result_glb(key).await? {
            Some(glb) => {
                let bytes = glb.len() as u64;
                let mut cache = self.cache.lock().unwrap();
                let known = cache.entries.get(key).map_or(bytes, |e| e.1);
                cache.touch(key, known);
                Ok(Ok(glb))
            }
            None => Ok(Err(self.recover(key).await?)),
        }
    }

    /// The preview sheet of a result, a mesh's or a level's: drawn on first asking from its kept
    /// input (a level's meshes from theirs) and its GLB, then stored beside it. None where there
    /// is no result.
    pub async fn preview(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        if let Some(png) = self.store.preview(key).await? {
            return Ok(Some(png));
        }
        let (Some(input), Some(glb), Some(report)) = (
            self.store.input(key).await?,
            self.store.result_glb(key).await?,
            self.store.result_report(key).await?,
        ) else {
            return Ok(None);
        };
        let limits = self.settings.ingest_limits();
        let drawn = if input.format == LEVEL_FORMAT {
            self.draw_level_preview(&input, glb, report).await
        } else {
            tokio::task::spawn_blocking(move || draw_preview(&input, &glb, &report, &limits))
                .await
                .ok()
                .flatten()
        };
        let Some(png) = drawn else {
            tracing::warn!(key, "cannot draw the preview of a stored result");
            return Ok(None);
        };
        self.store.put_preview(key, &png).await?;
        let mut cache = self.cache.lock().unwrap();
        if let Some(&(_, bytes)) = cache.entries.get(key) {
            cache.touch(key, bytes + png.len() as u64);
        }
        Ok(Some(png))
    }

    pub async fn result_report(&self, key: &str) -> StoreResult<Result<Vec<u8>, Option<String>>> {
        match self.store.result_report(key).await? {
            Some(report) => Ok(Ok(report)),
            None => Ok(Err(self.recover(key).await?)),
        }
    }

    /// After a missing or broken blob: drops what is left of the result and, if the input is
    /// still there, queues a job that makes it again.
    async fn recover(&self, key: &str) -> StoreResult<Option<String>> {
        let Some(meta) = self.store.result_meta(key).await? else {
            return Ok(None);
        };
        self.store.delete_result(key).await?;
        self.cache.lock().unwrap().remove(key);
        let Some(input) = self.store.input(key).await? else {
            tracing::warn!(
                key,
                "result was broken and its input is gone; it is cooked again on the next submission"
            );
            return Ok(None);
        };
        let settings = self.store.job(&meta.job).await?.map(|j| j.settings).unwrap_or_default();
        // Remade by the service itself: no token owns it.
        match self.submit(key, input, settings, None).await {
            Ok(Submitted::Queued(id)) | Ok(Submitted::Cached(id)) => Ok(Some(id)),
            Err(SubmitError::QueueFull(_) | SubmitError::OwnerQueueFull { .. }) => Ok(None),
            Err(SubmitError::Store(e)) => Err(e),
        }
    }

    pub async fn queue_depth(&self) -> StoreResult<usize> {
        self.store.queue_depth().await
    }

    /// What this node's gauges show.
    pub async fn activity(&self) -> StoreResult<Activity> {
        Ok(Activity {
            queue_depth: self.store.queue_depth().await?,
            running: self.live.lock().unwrap().len(),
            workers: self.workers.load(std::sync::atomic::Ordering::Relaxed),
            cache_bytes: self.cache.lock().unwrap().bytes,
            max_cache_bytes: self.settings.service.max_cache_bytes,
        })
    }

    async fn update_gauges(&self) {
        let Ok(activity) = self.activity().await else {
            return;
        };
        metrics::gauge!("occluder_jobs", "state" => "running").set(activity.running as f64);
        metrics::gauge!("occluder_workers").set(activity.workers as f64);
        metrics::gauge!("occluder_queue_depth").set(activity.queue_depth as f64);
        metrics::gauge!("occluder_cache_bytes").set(activity.cache_bytes as f64);
    }

    /// Runs one delivered job to its end: done with a stored result, or failed with an error.
    /// Only then does it leave the queue; if this process dies first, it is handed out again.
    /// While the store does not answer, the worker keeps the job, alive on the queue, and runs
    /// it again once the store answers: a wait is no new delivery, which would count toward
    /// `service.max_deliver` as a lost worker. Once `stop` turns true it leaves the job queued.
    async fn run(self: &Arc<Self>, delivery: Box<dyn Delivery>, stop: &watch::Receiver<bool>) {
        let delivery: Arc<dyn Delivery> = Arc::from(delivery);
        while self.run_once(&delivery).await == Ran::StoreDown {
            if !self.wait_for_store(delivery.as_ref(), stop).await {
                return;
            }
        }
    }

    /// Waits until the store answers about the delivered job, keeping the delivery alive
    /// meanwhile; false once `stop` turns true first.
    async fn wait_for_store(&self, delivery: &dyn Delivery, stop: &watch::Receiver<bool>) -> bool {
        let id = delivery.job_id();
        tracing::warn!(
            job = id,
            "the store does not answer; the job waits for it with its worker"
        );
        let mut stop = stop.clone();
        loop {
            if *stop.borrow() {
                tracing::warn!(
                    job = id,
                    "stopping while the store does not answer; the job stays queued"
                );
                return false;
            }
            let _ = delivery.keep_alive().await;
            if self.store.job(id).await.is_ok() {
                tracing::info!(job = id, "the store answers again; the job runs again");
                return true;
            }
            tokio::select! {
                () = tokio::time::sleep(POLL) => {}
                changed = stop.changed() => {
                    if changed.is_err() {
                        return false;
                    }
                }
            }
        }
    }

    /// [`Service::run`]'s one try: `StoreDown` where the store stopped answering first, with
    /// the job left on the queue.
    async fn run_once(self: &Arc<Self>, delivery: &Arc<dyn Delivery>) -> Ran {
        let id = delivery.job_id().to_string();
        let mut job = match self.store.job(&id).await {
            Ok(Some(job)) => job,
            Ok(None) => return self.let_go(Unwritten::Gone, delivery.as_ref()).await,
            Err(e) => {
                tracing::error!(job = id, error = %e, "cannot read a delivered job");
                return Ran::StoreDown;
            }
        };
        if job.state.is_finished() {
            // Cancelled while queued, or its worker stopped between finishing it and taking it
            // off the queue.
            return self.let_go(Unwritten::Ended(Box::new(job)), delivery.as_ref()).await;
        }
        job.attempts = delivery.deliveries();
        job.updated_ms = now_ms();
        let outcome = if job.attempts > self.settings.service.max_deliver {
            Err(JobError {
                code: "worker_lost".into(),
                message: format!(
                    "the job was started {} times and each time its worker stopped before finishing (a crash, a kill or running out of memory)",
                    job.attempts - 1
                ),
            })
        } else if let Some(meta) = self.result_meta(&job.key).await.ok().flatten() {
            // Its worker stored the result and stopped before recording the job done.
            tracing::info!(job = job.id, made_by = meta.job, "result already stored");
            Ok(())
        } else {
            job.state = JobState::Running;
            // Recorded, so that a restart knows this job was interrupted once already.
            match self.store.put_job_unless_ended(&job).await {
                Ok(Ok(())) => {}
                Ok(Err(unwritten)) => return self.let_go(unwritten, delivery.as_ref()).await,
                Err(e) => tracing::error!(job = job.id, error = %e, "cannot record the job as running"),
            }
            self.live.lock().unwrap().insert(id.clone(), job.clone());
            self.update_gauges().await;
            let (progress, tending, stop) = self.tend(&job, Arc::clone(delivery));
            let stored = match self.cook(&job, progress, stop).await {
                Ok(made) => self.store_result(&job, made).await,
                Err(unmade) => Err(unmade),
            };
            tending.abort();
            match stored {
                Ok(()) => Ok(()),
                Err(Unmade::Failed(e)) => Err(e),
                Err(Unmade::StoreDown) => {
                    self.live.lock().unwrap().remove(&id);
                    return Ran::StoreDown;
                }
            }
        };
        self.end(job, outcome, delivery.as_ref()).await
    }

    /// Takes a delivered job that has ended already, or has no record, off the queue, and a
    /// failed one's input with it: nothing cooks it again.
    async fn let_go(&self, unwritten: Unwritten, delivery: &dyn Delivery) -> Ran {
        match unwritten {
            Unwritten::Ended(job) if job.state == JobState::Failed => self.drop_input(&job).await,
            Unwritten::Ended(_) => {}
            Unwritten::Gone => {
                tracing::error!(job = delivery.job_id(), "queued job not found; dropped from the queue");
            }
        }
        let _ = delivery.finish().await;
        Ran::Ended
    }

    /// Stores a cooked job's result, retrying while the store does not answer.
    async fn store_result(&self, job: &Job, made: Made) -> Result<(), Unmade> {
        let Made {
            glb,
            report,
            input_bytes,
        } = made;
        let meta = ResultMeta {
            job: job.id.clone(),
            bytes: (glb.len() + report.len()) as u64 + input_bytes,
            created_ms: now_ms(),
        };
        patiently("store the result", &job.id, || {
            self.store.put_result(&job.key, &glb, &report, &meta)
        })
        .await?;
        self.cache.lock().unwrap().touch(&job.key, meta.bytes);
        Ok(())
    }

    /// Records how a job ended and takes it off the queue. A failed job's input goes once that
    /// is recorded: nothing will cook it again, and a new submission uploads it anew. Where the
    /// store does not answer, the job stays queued, its input kept, to end the same way again.
    /// Where the job was ended meanwhile (cancelled through another node), that end stands.
    async fn end(&self, mut job: Job, outcome: Result<(), JobError>, delivery: &dyn Delivery) -> Ran {
        let made_result = outcome.is_ok();
        match outcome {
            Ok(()) => {
                job.state = JobState::Done;
                job.progress = 1.0;
            }
            Err(e) => {
                tracing::warn!(job = job.id, error = e.message, "job failed");
                job.state = JobState::Failed;
                job.error = Some(e);
            }
        }
        job.updated_ms = now_ms();
        let recorded = patiently("record the finished job", &job.id, || {
            self.store.put_job_unless_ended(&job)
        })
        .await;
        self.live.lock().unwrap().remove(&job.id);
        match recorded {
            Err(_) => return Ran::StoreDown,
            Ok(Ok(())) => {}
            Ok(Err(Unwritten::Ended(ended))) => {
                tracing::info!(
                    job = job.id,
                    state = ended.state.name(),
                    "the job was ended meanwhile; that end stands"
                );
                job = *ended;
            }
            Ok(Err(Unwritten::Gone)) => {
                tracing::warn!(
                    job = job.id,
                    "the job's record is gone (ended and collected); its end is not recorded"
                );
            }
        }
        metrics::counter!("occluder_jobs_finished_total", "state" => job.state.name()).increment(1);
        // A result made is kept with its input, whatever the record says.
        if job.state == JobState::Failed && !made_result {
            if job.kind == JobKind::Level {
                self.drop_level_parts(&job).await;
            }
            self.drop_input(&job).await;
        }
        let _ = self.store.release(&job.key, &job.id).await;
        if let Err(e) = delivery.finish().await {
            tracing::warn!(job = job.id, error = %e, "cannot take the finished job off the queue; it comes back and ends at once");
        }
        if made_result {
            // A finished job's input is only needed to remake a broken result; it may go with
            // its result when the cache is full.
            self.evict().await;
        }
        tokio::task::spawn_blocking(release_free_memory);
        self.update_gauges().await;
        Ran::Ended
    }

    /// Deletes the records of jobs that ended more than `service.job_retention_s` ago, except
    /// those that made a stored result (a broken result is remade with their settings).
    pub async fn collect_jobs(&self) -> StoreResult<usize> {
        let makers: std::collections::HashSet<String> = self
            .store
            .results()
            .await?
            .into_iter()
            .map(|(_, meta)| meta.job)
            .collect();
        let retention_ms = (self.settings.service.job_retention_s * 1e3) as u64;
        let before_ms = now_ms().saturating_sub(retention_ms);
        let mut collected = 0;
        for job in self.store.jobs().await? {
            if job.state.is_finished() && job.updated_ms < before_ms && !makers.contains(&job.id) {
                self.store.delete_job(&job.id).await?;
                collected += 1;
            }
        }
        metrics::counter!("occluder_jobs_collected_total").increment(collected as u64);
        Ok(collected)
    }

    /// Deletes the inputs of a failed level's uploaded meshes that have no result: nothing
    /// cooks them now, and the next upload of the level sends them again.
    async fn drop_level_parts(&self, job: &Job) {
        let Ok(Some(input)) = self.store.input(&job.key).await else {
            return;
        };
        let Ok(manifest) = crate::level::parse_manifest("the level", &input.bytes) else {
            return;
        };
        let mut keys: Vec<&str> = manifest.instances.iter().map(|i| i.mesh.as_str()).collect();
        keys.sort_unstable();
        keys.dedup();
        for key in keys {
            if matches!(self.store.result_meta(key).await, Ok(None))
                && let Err(e) = self.store.delete_input(key).await
            {
                tracing::warn!(job = job.id, key, error = %e, "cannot delete a failed level's mesh");
            }
        }
    }

    /// Deletes the input of `job`, which has failed, unless another job holds its key now (and
    /// needs the same bytes): the claim is held, or taken, while the input goes.
    async fn drop_input(&self, job: &Job) {
        match self.store.claim(&job.key, &job.id).await {
            Ok(None) => {}
            Ok(Some(holder)) if holder.job == job.id => {}
            _ => return,
        }
        if let Err(e) = self.store.delete_input(&job.key).await {
            tracing::warn!(job = job.id, error = %e, "cannot delete the failed job's input");
        }
        let _ = self.store.release(&job.key, &job.id).await;
    }

    /// While a job runs: writes its progress where other nodes read it, keeps its delivery
    /// alive, and raises its stop flag once its record says another node cancelled it. Returns
    /// where the cook sends progress, the task to abort at the end, and the stop flag.
    fn tend(&self, job: &Job, delivery: Arc<dyn Delivery>) -> (watch::Sender<Job>, tokio::task::JoinHandle<()>, Stop) {
        let id = job.id.clone();
        let stop = self.stop_flag(&id);
        let raise = Arc::clone(&stop);
        let (progress, mut updates) = watch::channel(job.clone());
        let store = Arc::clone(&self.store);
        let beat = Duration::from_secs_f64(self.settings.service.ack_wait_s / 3.0);
        let task = tokio::spawn(async move {
            let mut ticks = tokio::time::interval(beat);
            loop {
                tokio::select! {
                    changed = updates.changed() => {
                        if changed.is_err() {
                            break;
                        }
                        let job = updates.borrow_and_update().clone();
                        match store.put_progress(&job).await {
                            Ok(Ok(())) => {}
                            Ok(Err(_)) => raise.store(true, std::sync::atomic::Ordering::Relaxed),
                            Err(e) => tracing::debug!(job = job.id, error = %e, "progress not written"),
                        }
                    }
                    _ = ticks.tick() => {
                        if let Err(e) = delivery.keep_alive().await {
                            tracing::warn!(error = %e, "cannot keep the job alive on the queue");
                        }
                        if let Ok(recorded) = store.job(&id).await
                            && recorded.is_none_or(|r| r.state.is_finished())
                        {
                            raise.store(true, std::sync::atomic::Ordering::Relaxed);
                        }
                    }
                }
            }
        });
        (progress, task, stop)
    }

    /// Ingests and cooks on a blocking thread; a panic fails this job only.
    async fn cook(self: &Arc<Self>, job: &Job, progress: watch::Sender<Job>, stop: Stop) -> Result<Made, Unmade> {
        let fail = |code: &str, message: String| JobError {
            code: code.into(),
            message,
        };
        let Some(input) = patiently("read the input", &job.id, || self.store.input(&job.key)).await? else {
            return Err(fail("input_missing", "the uploaded mesh is gone".into()).into());
        };
        let input_bytes = input.encode().len() as u64;
        if job.kind == JobKind::Level {
            let (glb, report) = self.bake_level(job, input, progress, stop).await?;
            return Ok(Made {
                glb,
                report,
                input_bytes,
            });
        }
        let mut settings = self.settings.clone();
        match serde_json::from_value(job.settings.clone()) {
            Ok(cook) => settings.cook = cook,
            Err(e) => return Err(fail("bad_settings", e.to_string()).into()),
        }
        let service = Arc::clone(self);
        let running = job.clone();
        let limit = self.settings.service.job_timeout_s;
        let work = tokio::task::spawn_blocking(move || {
            let start = std::time::Instant::now();
            let (mesh, stats) = input
                .load(&settings.ingest_limits())
                .map_err(|e| fail("bad_mesh", e.to_string()))?;
            let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
            let progress = |stage: &str, done: f64| {
                halt(&stop, start, limit)?;
                service.set_progress(&running, &progress, stage, done);
                Ok(())
            };
            let cooked = cook_with_progress(mesh, stats, ingest_ms, &settings, settings.service.evaluate, &progress)
                .map_err(|e| cook_failure(e, limit))?;
            for (stage, ms) in &cooked.report.timings_ms.0 {
                metrics::histogram!("occluder_cook_stage_seconds", "stage" => stage.clone()).record(ms / 1e3);
            }
            metrics::histogram!("occluder_cook_seconds").record(cooked.report.total_ms() / 1e3);
            let report = serde_json::to_vec_pretty(&cooked.report).expect("reports serialize");
            Ok::<_, JobError>((cooked.glb(), report))
        });
        match work.await {
            Ok(Ok((glb, report))) => Ok(Made {
                glb,
                report,
                input_bytes,
            }),
            Ok(Err(e)) => Err(e.into()),
            Err(e) => Err(fail("panic", format!("the cook crashed: {e}")).into()),
        }
    }

    /// The flag that stops job `id` at its next stage, made now. The map keeps it only while
    /// the job's cook holds it: the flags of ended jobs go as the next one is made.
    fn stop_flag(&self, id: &str) -> Stop {
        let flag = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut stops = self.stops.lock().unwrap();
        stops.retain(|_, held| held.strong_count() > 0);
        stops.insert(id.to_string(), Arc::downgrade(&flag));
        flag
    }

    /// Cancels a job that has not finished: it ends `failed` with code `cancelled`. A queued job
    /// never starts; one running here stops at its next stage; one running on another node
    /// stops when that node next writes or reads its record. Returns the job as recorded, or
    /// why it could not be cancelled: it ended first, or its record is gone.
    pub async fn cancel(&self, mut job: Job) -> StoreResult<Result<Job, Unwritten>> {
        job.state = JobState::Failed;
        job.error = Some(JobError {
            code: CANCELLED.into(),
            message: "cancelled by DELETE /v1/jobs/{id}".replace("{id}", &job.id),
        });
        job.updated_ms = now_ms();
        if let Err(unwritten) = self.store.put_job_unless_ended(&job).await? {
            return Ok(Err(unwritten));
        }
        if let Some(stop) = self
            .stops
            .lock()
            .unwrap()
            .get(&job.id)
            .and_then(std::sync::Weak::upgrade)
        {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        metrics::counter!("occluder_jobs_cancelled_total").increment(1);
        Ok(Ok(job))
    }

    fn set_progress(&self, running: &Job, progress: &watch::Sender<Job>, stage: &str, done: f64) {
        let mut job = running.clone();
        job.stage = Some(stage.to_string());
        job.progress = done;
        if let Some(slot) = self.live.lock().unwrap().get_mut(&job.id) {
            *slot = job.clone();
        }
        progress.send_replace(job);
    }

    /// Bakes a level whose meshes are all keys: each is found in the store, or cooked from its
    /// kept upload (and filed under its key for the next level). The report holds the batches.
    async fn bake_level(
        self: &Arc<Self>,
        job: &Job,
        input: store::Input,
        progress: watch::Sender<Job>,
        stop: Stop,
    ) -> Result<(Vec<u8>, Vec<u8>), Unmade> {
        let fail = |code: &str, message: String| JobError {
            code: code.into(),
            message,
        };
        let mut settings = self.settings.clone();
        match serde_json::from_value::<LevelJobSettings>(job.settings.clone()) {
            Ok(level) => (settings.cook, settings.level) = (level.cook, level.level),
            Err(e) => return Err(fail("bad_settings", e.to_string()).into()),
        }
        let level = crate::level::parse_manifest("the level", &input.bytes)
            .and_then(|m| crate::level::Level::from_manifest(m, |mesh| Some(crate::level::MeshRef::Key(mesh.into()))))
            .map_err(|e| fail("bad_level", e.to_string()))?;
        let service = Arc::clone(self);
        let running = job.clone();
        let runtime = tokio::runtime::Handle::current();
        // The bake is CPU-bound (rayon) between its store calls: it runs on a blocking thread.
        let limit = self.settings.service.job_timeout_s;
        let work = tokio::task::spawn_blocking(move || {
            let start = std::time::Instant::now();
            let progress = |done: usize, total: usize| {
                service.set_progress(&running, &progress, "meshes", 0.95 * done as f64 / total.max(1) as f64)
            };
            let halt = |_: &str, _: f64| halt(&stop, start, limit);
            runtime.block_on(crate::level::bake(
                &level,
                &settings,
                service.store.as_ref(),
                &progress,
                &halt,
            ))
        });
        let baked = match work.await {
            Ok(Ok(baked)) => baked,
            Ok(Err(crate::level::LevelError::Cook(e))) => return Err(cook_failure(e, limit).into()),
            Ok(Err(crate::level::LevelError::Store(e))) => return Err(e.into()),
            Ok(Err(e @ crate::level::LevelError::Cache(_))) => return Err(fail("storage", e.to_string()).into()),
            Ok(Err(e)) => return Err(fail("bad_level", e.to_string()).into()),
            Err(e) => return Err(fail("panic", format!("the bake crashed: {e}")).into()),
        };
        {
            let mut cache = self.cache.lock().unwrap();
            for (key, bytes) in &baked.stored {
                cache.touch(key, *bytes);
            }
        }
        let mut report = serde_json::to_value(&baked.report).expect("reports serialize");
        report["batches"] = serde_json::to_value(&baked.batches).expect("batches serialize");
        Ok((
            baked.glb,
            serde_json::to_vec_pretty(&report).expect("reports serialize"),
        ))
    }

    /// Drops least recently used results (and their inputs) beyond `service.max_cache_bytes`.
    async fn evict(&self) {
        let limit = self.settings.service.max_cache_bytes;
        loop {
            let victim = {
                let cache = self.cache.lock().unwrap();
                if cache.bytes <= limit {
                    return;
                }
                // Results of keys in hand (a recompute under way) stay.
                let live = self.live.lock().unwrap();
                cache.oldest(|k| live.values().any(|job| job.key == k))
            };
            let Some(key) = victim else { return };
            tracing::info!(key, "evicting the least recently used result");
            metrics::counter!("occluder_evictions_total").increment(1);
            let dropped = async {
                self.store.delete_result(&key).await?;
                self.store.delete_input(&key).await
            }
            .await;
            if let Err(e) = dropped {
                tracing::error!(key, error = %e, "cannot evict");
                return;
            }
            self.cache.lock().unwrap().remove(&key);
        }
    }
}

impl Service {
    /// A level's preview sheet (PNG): its manifest read again, its meshes from their kept
    /// uploads, and the report's batches and cull figures. None where a mesh is gone.
    async fn draw_level_preview(&self, input: &store::Input, glb: Vec<u8>, report: Vec<u8>) -> Option<Vec<u8>> {
        use crate::level::{self, preview::LevelCaption};
        let manifest = level::parse_manifest("the level", &input.bytes).ok()?;
        let level = level::Level::from_manifest(manifest, |mesh| Some(level::MeshRef::Key(mesh.into()))).ok()?;
        let report: serde_json::Value = serde_json::from_slice(&report).ok()?;
        let batches = report["batches"].as_array()?;
        let groups: Vec<Vec<usize>> = batches
            .iter()
            .map(|b| serde_json::from_value(b["instances"].clone()).unwrap_or_default())
            .collect();
        let cull = &report["cull"];
        let caption = LevelCaption {
            name: report["name"]
                .as_str()
                .filter(|n| !n.is_empty())
                .unwrap_or("level")
                .into(),
            instances: level.instances.len(),
            batches: groups.len(),
            triangles: report["triangles_after"].as_u64().unwrap_or(0) as usize,
            cull: cull["culled_share"].as_f64().map(|share| {
                let count = |name: &str| cull[name].as_u64().unwrap_or(0) as usize;
                (share, count("wrongly_culled"), count("cameras"))
            }),
        };
        let (store, limits) = (Arc::clone(&self.store), self.settings.ingest_limits());
        let runtime = tokio::runtime::Handle::current();
        // Drawing is CPU-bound between the store's reads: it runs on a blocking thread.
        let drawn = tokio::task::spawn_blocking(move || {
            let meshes = runtime
                .block_on(level::placed_meshes(&level, store.as_ref(), &limits))
                .ok()?;
            let occluder = level::occluder_mesh(&glb).ok()?;
            let sheet = level::preview::sheet(&level, &meshes, &occluder, &groups, &caption).ok()?;
            Some(crate::eval::preview::png(&sheet))
        });
        drawn.await.ok().flatten()
    }
}

/// The preview sheet (PNG) of a result: its input read again, the GLB's solid and panels over
/// it, and the report's figures in the caption. None where the input or GLB cannot be read.
fn draw_preview(
    input: &store::Input,
    glb: &[u8],
    report: &[u8],
    limits: &crate::mesh::IngestLimits,
) -> Option<Vec<u8>> {
    use crate::eval::preview::{self, Caption, Piece};
    let (original, _) = input.load(limits).ok()?;
    let mut pieces = Vec::new();
    for (name, mesh) in crate::mesh::glb::read_parts(glb).ok()? {
        let piece = if name == crate::occluder::PANELS_PART {
            Piece::Panels
        } else {
            Piece::Boxes
        };
        pieces.extend(preview::pieces_of_mesh(&mesh, piece));
    }
    let report: serde_json::Value = serde_json::from_slice(report).ok()?;
    let quality = &report["quality"];
    let caption = Caption {
        name: report["key"].as_str().unwrap_or_default().chars().take(16).collect(),
        triangles_in: report["input"]["triangles"].as_u64().unwrap_or(0) as usize,
        triangles_out: report["occluder"]["triangles"].as_u64().unwrap_or(0) as usize,
        openings: report["openings_closed"]
            .as_array()
            .into_iter()
            .flatten()
            .flat_map(|o| serde_json::from_value::<Vec<Vec<[f64; 3]>>>(o["outline"].clone()).unwrap_or_default())
            .collect(),
        judged: quality["coverage"].as_f64().map(|coverage| {
            (
                coverage,
                quality["false_pixels"].as_u64().unwrap_or(0),
                quality["views"].as_u64().unwrap_or(0) as usize,
            )
        }),
    };
    let (sheet, _) = preview::sheet(&original, &pieces, &caption);
    Some(preview::png(&sheet))
}

/// Why a running job must stop now: cancelled (its flag raised) or past `limit` seconds since
/// `start`.
fn halt(stop: &Stop, start: std::time::Instant, limit: f64) -> Result<(), String> {
    if stop.load(std::sync::atomic::Ordering::Relaxed) {
        return Err(CANCELLED.to_string());
    }
    if start.elapsed().as_secs_f64() > limit {
        return Err(TIMEOUT.to_string());
    }
    Ok(())
}

/// The job error of a cook that did not finish; `limit` is service.job_timeout_s.
fn cook_failure(e: CookError, limit: f64) -> JobError {
    let (code, message) = match e {
        CookError::Stopped { stage, reason } if reason == TIMEOUT => (
            TIMEOUT.to_string(),
            format!("the job ran past service.job_timeout_s ({limit} s) and stopped before stage `{stage}`"),
        ),
        CookError::Stopped { stage, reason } => (reason, format!("cancelled; stopped before stage `{stage}`")),
        CookError::Gpu(e) => ("gpu".to_string(), e.to_string()),
    };
    JobError { code, message }
}

/// Why a job made no result.
enum Unmade {
    /// It failed for good, for the reason given.
    Failed(JobError),
    /// The store stopped answering: the job stays on the queue, to run again once it answers.
    StoreDown,
}

impl From<JobError> for Unmade {
    fn from(e: JobError) -> Self {
        Unmade::Failed(e)
    }
}

impl From<StoreError> for Unmade {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::Backend(_) => Unmade::StoreDown,
            StoreError::Decode(_) => Unmade::Failed(JobError {
                code: "storage".into(),
                message: e.to_string(),
            }),
        }
    }
}

/// Gives the memory a finished job freed back to the system. glibc keeps freed heap for reuse,
/// so without this the server's RSS stays at the highest point its jobs ever reached together.
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim takes no pointers; it only returns glibc's unused pages to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// How long a worker waits on the queue, or for the store to answer, before it looks again.
const POLL: Duration = Duration::from_secs(1);

/// How a try at a delivered job ended.
#[derive(PartialEq)]
enum Ran {
    /// Done or failed, and off the queue; or not a job to run.
    Ended,
    /// The store stopped answering: the job is still on the queue, unfinished.
    StoreDown,
}

/// Runs `workers` tasks that take jobs from the store's queue until `stop` turns true; each
/// finishes the job in hand first. Jobs still queued stay on the queue.
pub async fn run_workers(service: Arc<Service>, workers: usize, stop: watch::Receiver<bool>) {
    // Under auto a cook opens the GPU only where it pays for the opening, unless the process
    // has it open: the pool opens it first, so that every job runs where it pays.
    let device = service.settings.cook.device;
    if device != crate::gpu::DeviceChoice::Cpu {
        match tokio::task::spawn_blocking(move || crate::gpu::for_choice(device)).await {
            Ok(Ok(placement)) => placement.why_cpu.iter().for_each(|why| tracing::info!("{why}")),
            Ok(Err(e)) => tracing::warn!(error = %e, "no GPU for the workers"),
            Err(e) => tracing::warn!(error = %e, "opening the GPU stopped"),
        }
    }
    service.workers.fetch_add(workers, std::sync::atomic::Ordering::Relaxed);
    service.update_gauges().await;
    let tasks: Vec<_> = (0..workers)
        .map(|_| {
            let (service, stop) = (Arc::clone(&service), stop.clone());
            tokio::spawn(async move {
                while !*stop.borrow() {
                    match service.store.next_job(POLL).await {
                        Ok(Some(delivery)) => service.run(delivery, &stop).await,
                        Ok(None) => {}
                        Err(e) => {
                            tracing::warn!(error = %e, "cannot take a job from the queue; retrying");
                            tokio::time::sleep(POLL).await;
                        }
                    }
                }
            })
        })
        .collect();
    for task in tasks {
        let _ = task.await;
    }
    service.workers.fetch_sub(workers, std::sync::atomic::Ordering::Relaxed);
}

/// The store the settings name: NATS JetStream at `service.nats_url`, or sled under
/// `service.data_dir`.
async fn open_store(settings: &Settings) -> anyhow::Result<Arc<dyn Store>> {
    use anyhow::Context;
    if !settings.service.nats_url.is_empty() {
        return Ok(Arc::new(store::nats::NatsStore::open(&settings.service).await?));
    }
    let dir = settings.service.data_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(Arc::new(store::sled::SledStore::open(
        &dir,
        settings.service.sled_cache_bytes,
    )?))
}

/// Resolves on SIGTERM or Ctrl-C.
async fn terminated() {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).expect("SIGTERM handler");
    tokio::select! {
        _ = term.recv() => {}
        _ = tokio::signal::ctrl_c() => {}
    }
}

/// Runs the HTTP API (and, unless `api_only`, the workers) until SIGTERM or Ctrl-C. Prints
/// `listening on ADDR` once it accepts connections.
pub async fn serve(settings: Settings, api_only: bool, insecure_no_auth: bool) -> anyhow::Result<()> {
    use anyhow::Context;
    let tokens = tokens_of(&settings, insecure_no_auth)?;
    let metrics = metrics_exporter_prometheus::PrometheusBuilder::new()
        .set_buckets(&[
            0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
        ])
        .expect("buckets are not empty")
        .install_recorder()
        .context("cannot install the metrics recorder")?;
    let store = open_store(&settings).await?;
    let workers = settings.service.workers;
    let listen = settings.service.listen.clone();
    let service = Service::start(store, settings).await?;
    let (stop, stopped) = watch::channel(false);
    let pool = (!api_only).then(|| tokio::spawn(run_workers(Arc::clone(&service), workers, stopped.clone())));
    let app = api::router(api::AppState {
        service: Arc::clone(&service),
        metrics,
        shutdown: stopped,
        tokens: tokens.clone(),
    });
    if let Some(tokens) = tokens {
        tokio::spawn(reload_on_hangup(tokens));
    }
    tokio::spawn(collect_jobs_periodically(Arc::clone(&service)));
    let tls = match (&service.settings.service.tls_cert, &service.settings.service.tls_key) {
        (cert, key) if !cert.is_empty() => Some(tls::Tls::open(cert.as_ref(), key.as_ref()).await?),
        _ => None,
    };
    let listener = std::net::TcpListener::bind(&listen).with_context(|| format!("cannot listen on {listen}"))?;
    listener.set_nonblocking(true)?;
    println!("listening on {}", listener.local_addr()?);
    let shutdown = async move {
        terminated().await;
        tracing::info!("shutting down: no new connections; running jobs finish, queued ones stay queued");
        let _ = stop.send(true);
    };
    match tls {
        Some(tls) => {
            let handle = axum_server::Handle::new();
            let closing = handle.clone();
            tokio::spawn(async move {
                shutdown.await;
                closing.graceful_shutdown(None);
            });
            tokio::spawn(tls.clone().reload_on_change());
            axum_server::tls_rustls::from_tcp_rustls(listener, tls.config)?
                .handle(handle)
                .serve(app.into_make_service())
                .await?;
        }
        None => {
            let listener = tokio::net::TcpListener::from_std(listener)?;
            axum::serve(listener, app).with_graceful_shutdown(shutdown).await?;
        }
    }
    if let Some(pool) = pool {
        let _ = pool.await;
    }
    service.store.flush().await?;
    Ok(())
}

/// The tokens that may call, with `service.auth = "tokens"`. With `none`, only a loopback
/// address is served, unless `insecure_no_auth`.
fn tokens_of(settings: &Settings, insecure_no_auth: bool) -> anyhow::Result<Option<Arc<auth::Tokens>>> {
    let service = &settings.service;
    match service.auth {
        crate::config::AuthMode::Tokens if service.tokens_file.is_empty() => {
            anyhow::bail!("service.auth = \"tokens\" needs service.tokens_file (see `occluder-cook token new`)")
        }
        crate::config::AuthMode::Tokens => Ok(Some(Arc::new(
            auth::Tokens::open(
                std::path::Path::new(&service.tokens_file),
                service.token_submissions_per_s,
                service.token_submission_burst,
            )
            .map_err(anyhow::Error::msg)?,
        ))),
        crate::config::AuthMode::None if !insecure_no_auth && !is_loopback(&service.listen) => anyhow::bail!(
            "service.listen = {} is reachable from other machines and service.auth = \"none\": set service.auth = \"tokens\" or pass --insecure-no-auth",
            service.listen
        ),
        crate::config::AuthMode::None => Ok(None),
    }
}

/// Whether `listen` (host:port) is a loopback address.
fn is_loopback(listen: &str) -> bool {
    match listen.parse::<std::net::SocketAddr>() {
        Ok(address) => address.ip().is_loopback(),
        Err(_) => listen.rsplit_once(':').is_some_and(|(host, _)| host == "localhost"),
    }
}

/// Collects ended jobs' records at start and then every `service.job_retention_s`, at most
/// every 10 minutes.
async fn collect_jobs_periodically(service: Arc<Service>) {
    let every = Duration::from_secs_f64(service.settings.service.job_retention_s.min(600.0));
    let mut ticks = tokio::time::interval(every);
    loop {
        ticks.tick().await;
        match service.collect_jobs().await {
            Ok(0) => {}
            Ok(n) => tracing::info!(jobs = n, "collected the records of jobs past service.job_retention_s"),
            Err(e) => tracing::warn!(error = %e, "cannot collect old job records"),
        }
    }
}

/// Reads the tokens file again on each SIGHUP.
async fn reload_on_hangup(tokens: Arc<auth::Tokens>) {
    use tokio::signal::unix::{SignalKind, signal};
    let Ok(mut hangups) = signal(SignalKind::hangup()) else {
        return;
    };
    while hangups.recv().await.is_some() {
        tokens.reload();
    }
}

/// Runs workers only, on the NATS store, until SIGTERM or Ctrl-C. Prints `worker ready` once it
/// takes jobs.
pub async fn work(settings: Settings) -> anyhow::Result<()> {
    if settings.service.nats_url.is_empty() {
        anyhow::bail!(
            "a worker node needs NATS (--nats URL or service.nats_url): sled is the store of one process, which `serve` runs with its own workers"
        );
    }
    let store = open_store(&settings).await?;
    let workers = settings.service.workers;
    let service = Service::start(store, settings).await?;
    let (stop, stopped) = watch::channel(false);
    let pool = tokio::spawn(run_workers(Arc::clone(&service), workers, stopped));
    println!("worker ready");
    terminated().await;
    tracing::info!("shutting down: the jobs in hand finish, queued ones stay queued");
    let _ = stop.send(true);
    let _ = pool.await;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{Lru, Service, StoreError, Submitted, Unmade};
    use crate::store::job::{Job, JobError, JobKind, JobState, now_ms};
    use crate::store::{Input, ResultMeta, Store, sled::SledStore};
    use std::sync::Arc;

    /// A cancel can land after the worker stored the result and before it recorded the job
    /// done; the result stays. A later submission of the same mesh is served it as a done job,
    /// not as the cancelled one.
    #[tokio::test]
    async fn a_result_whose_maker_was_cancelled_is_served_as_done() {
        let dir = std::env::temp_dir().join(format!("occluder-cook-cancelled-maker-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let store: Arc<dyn Store> = Arc::new(SledStore::open(&dir, 1 << 20).unwrap());
        let service = Service::start(Arc::clone(&store), crate::config::load(None, &[]).unwrap())
            .await
            .unwrap();
        let maker = Job {
            state: JobState::Failed,
            progress: 0.5,
            error: Some(JobError {
                code: "cancelled".into(),
                message: "cancelled".into(),
            }),
            attempts: 1,
            ..Job::queued(JobKind::Mesh, "key", serde_json::Value::Null, None)
        };
        store.put_job(&maker).await.unwrap();
        let made = ResultMeta {
            job: maker.id.clone(),
            bytes: 8,
            created_ms: now_ms(),
        };
        store.put_result("key", b"glb!", b"{}", &made).await.unwrap();
        let input = || Input {
            format: "obj".into(),
            bytes: b"v 0 0 0".to_vec(),
        };
        let submit = || service.submit("key", input(), serde_json::Value::Null, Some("ci".into()));
        let Submitted::Cached(served) = submit().await.unwrap() else {
            panic!("a stored result was queued again");
        };
        assert_ne!(served, maker.id, "served as the cancelled job");
        let record = store.job(&served).await.unwrap().expect("the served job is recorded");
        assert_eq!(
            (record.state, record.key.as_str(), record.owner.as_deref()),
            (JobState::Done, "key", Some("ci"))
        );
        assert_eq!(
            store.job(&maker.id).await.unwrap(),
            Some(maker.clone()),
            "the cancel stands"
        );
        // A maker that ended done is the job served, as before.
        store
            .put_job(&Job {
                state: JobState::Done,
                error: None,
                ..maker.clone()
            })
            .await
            .unwrap();
        assert!(matches!(submit().await.unwrap(), Submitted::Cached(id) if id == maker.id));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn lru_finds_the_least_recently_used_key_not_kept() {
        let mut lru = Lru::default();
        for (key, bytes) in [("a", 10), ("b", 20), ("c", 30)] {
            lru.touch(key, bytes);
        }
        lru.touch("a", 15);
        assert_eq!(lru.bytes, 65);
        assert_eq!(lru.oldest(|_| false).as_deref(), Some("b"));
        assert_eq!(lru.oldest(|k| k == "b").as_deref(), Some("c"));
        lru.remove("b");
        assert_eq!(lru.bytes, 45);
        assert_eq!(lru.oldest(|_| false).as_deref(), Some("c"));
        assert_eq!(lru.oldest(|_| true), None);
        assert_eq!(lru.by_use.len(), lru.entries.len());
    }

    #[test]
    fn a_store_that_does_not_answer_leaves_the_job_queued_and_an_unreadable_record_fails_it() {
        let down = Unmade::from(StoreError::Backend("nats: missed idle heartbeat".into()));
        assert!(matches!(down, Unmade::StoreDown));
        match Unmade::from(StoreError::Decode("truncated".into())) {
            Unmade::Failed(e) => assert_eq!(
                (e.code.as_str(), e.message.as_str()),
                ("storage", "stored record is unreadable: truncated")
            ),
            Unmade::StoreDown => panic!("an unreadable record was left queued"),
        }
    }
}
