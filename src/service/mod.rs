//! The cook service: an HTTP API ([`api`]) over a durable job queue, a pool of workers that run
//! the pipeline, and a content-addressed result cache, all kept in a [`store::Store`].
//!
//! A job is durable before its submission is answered. On start, queued and running jobs of a
//! previous run (a crash, a kill -9) are queued again. Identical work is never done twice: a
//! submission whose key has a result gets it, and one whose key is already queued or running
//! gets that job.

pub mod api;
pub mod client;
pub mod job;
pub mod store;

use crate::config::Settings;
use crate::cook::cook_with_progress;
use job::{Job, JobError, JobKind, JobState, now_ms};
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use store::{Input, ResultMeta, Store, StoreResult};
use tokio::sync::{mpsc, watch};

/// Shared by the API handlers and the workers.
pub struct Service {
    pub store: Arc<dyn Store>,
    /// The server's settings; a job's query parameters override `cook.*` keys.
    pub settings: Settings,
    queue: mpsc::UnboundedSender<String>,
    queued: AtomicUsize,
    /// Jobs queued or running, by id, with their latest state (progress is not written to the
    /// store at every stage).
    live: Mutex<HashMap<String, Job>>,
    /// Queued or running job id by key: identical work joins it.
    active: Mutex<HashMap<String, String>>,
    cache: Mutex<Lru>,
    /// Keys of uploads seen before, by the BLAKE3 of their bytes, format and settings: a repeat
    /// upload skips parsing.
    seen: Mutex<HashMap<blake3::Hash, String>>,
}

/// The input format of a level job: its manifest, every mesh given by key.
pub const LEVEL_FORMAT: &str = "level";

/// A level job's settings.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct LevelJobSettings {
    pub cook: crate::config::CookSettings,
    pub level: crate::config::LevelSettings,
}

/// Most remembered uploads; the memo starts over beyond it.
const SEEN_UPLOADS: usize = 100_000;

/// Least recently used results, by key: (last access, bytes).
#[derive(Default)]
struct Lru {
    entries: HashMap<String, (u64, u64)>,
    bytes: u64,
    clock: u64,
}

impl Lru {
    fn touch(&mut self, key: &str, bytes: u64) {
        self.clock += 1;
        if let Some(old) = self.entries.insert(key.to_string(), (self.clock, bytes)) {
            self.bytes -= old.1;
        }
        self.bytes += bytes;
    }

    fn remove(&mut self, key: &str) {
        if let Some((_, bytes)) = self.entries.remove(key) {
            self.bytes -= bytes;
        }
    }

    /// The least recently used key that `keep` does not hold on to.
    fn oldest(&self, keep: impl Fn(&str) -> bool) -> Option<String> {
        self.entries
            .iter()
            .filter(|(k, _)| !keep(k))
            .min_by_key(|(_, (used, _))| *used)
            .map(|(k, _)| k.clone())
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
    #[error(transparent)]
    Store(#[from] store::StoreError),
}

impl Service {
    /// Opens the service on `store`, queueing again the jobs a previous run left unfinished.
    /// Returns it and the receiving end of the queue, for [`run_workers`].
    pub async fn start(
        store: Arc<dyn Store>,
        settings: Settings,
    ) -> StoreResult<(Arc<Service>, mpsc::UnboundedReceiver<String>)> {
        let (tx, rx) = mpsc::unbounded_channel();
        let service = Arc::new(Service {
            store,
            settings,
            queue: tx,
            queued: AtomicUsize::new(0),
            live: Mutex::new(HashMap::new()),
            active: Mutex::new(HashMap::new()),
            cache: Mutex::new(Lru::default()),
            seen: Mutex::new(HashMap::new()),
        });
        // Oldest first, so that the least recently made is the first to go.
        let mut results = service.store.results().await?;
        results.sort_by_key(|(_, meta)| meta.created_ms);
        for (key, meta) in results {
            service.cache.lock().unwrap().touch(&key, meta.bytes);
        }
        for mut job in service.store.unfinished_jobs().await? {
            tracing::info!(job = job.id, key = job.key, "queueing again a job left unfinished");
            job.state = JobState::Queued;
            job.updated_ms = now_ms();
            service.store.put_job(&job).await?;
            service.enqueue(job);
        }
        service.update_gauges();
        Ok((service, rx))
    }

    fn enqueue(&self, job: Job) {
        self.active.lock().unwrap().insert(job.key.clone(), job.id.clone());
        let id = job.id.clone();
        self.live.lock().unwrap().insert(id.clone(), job);
        self.queued.fetch_add(1, Ordering::SeqCst);
        // The receiver lives as long as the workers; after shutdown the job stays in the store.
        let _ = self.queue.send(id);
    }

    /// Files a job for `input` under `key`, unless the result exists or the key is in hand.
    pub async fn submit(&self, key: &str, input: Input, settings: serde_json::Value) -> Result<Submitted, SubmitError> {
        if let Some(meta) = self.result_meta(key).await? {
            metrics::counter!("occluder_cache_hits_total").increment(1);
            return Ok(Submitted::Cached(meta.job));
        }
        if let Some(id) = self.active.lock().unwrap().get(key) {
            metrics::counter!("occluder_dedup_joins_total").increment(1);
            return Ok(Submitted::Queued(id.clone()));
        }
        metrics::counter!("occluder_cache_misses_total").increment(1);
        let waiting = self.queued.load(Ordering::SeqCst);
        if waiting >= self.settings.service.max_queue {
            return Err(SubmitError::QueueFull(waiting));
        }
        let now = now_ms();
        let kind = if input.format == LEVEL_FORMAT {
            JobKind::Level
        } else {
            JobKind::Mesh
        };
        let job = Job {
            id: job::new_id(),
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
        };
        // Claim the key first, so that an identical submission arriving now joins this job.
        {
            let mut active = self.active.lock().unwrap();
            if let Some(id) = active.get(key) {
                return Ok(Submitted::Queued(id.clone()));
            }
            active.insert(key.to_string(), job.id.clone());
            self.live.lock().unwrap().insert(job.id.clone(), job.clone());
        }
        let stored = async {
            self.store.put_input(key, &input).await?;
            self.store.put_job(&job).await
        }
        .await;
        if let Err(e) = stored {
            self.active.lock().unwrap().remove(key);
            self.live.lock().unwrap().remove(&job.id);
            return Err(e.into());
        }
        let id = job.id.clone();
        self.enqueue(job);
        self.update_gauges();
        Ok(Submitted::Queued(id))
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
        match self.submit(key, input, settings).await {
            Ok(Submitted::Queued(id)) | Ok(Submitted::Cached(id)) => Ok(Some(id)),
            Err(SubmitError::QueueFull(_)) => Ok(None),
            Err(SubmitError::Store(e)) => Err(e),
        }
    }

    pub fn queue_depth(&self) -> usize {
        self.queued.load(Ordering::SeqCst)
    }

    fn update_gauges(&self) {
        let live = self.live.lock().unwrap();
        for state in [JobState::Queued, JobState::Running] {
            let n = live.values().filter(|j| j.state == state).count();
            metrics::gauge!("occluder_jobs", "state" => state.name()).set(n as f64);
        }
        metrics::gauge!("occluder_queue_depth").set(self.queued.load(Ordering::SeqCst) as f64);
        metrics::gauge!("occluder_cache_bytes").set(self.cache.lock().unwrap().bytes as f64);
    }

    fn set_live(&self, job: &Job) {
        if let Some(slot) = self.live.lock().unwrap().get_mut(&job.id) {
            *slot = job.clone();
        }
    }

    /// Runs one job to its end: done with a stored result, or failed with an error.
    async fn run(self: &Arc<Self>, id: String) {
        self.queued.fetch_sub(1, Ordering::SeqCst);
        let Some(mut job) = self.job(&id).await.ok().flatten() else {
            tracing::error!(job = id, "queued job not found");
            return;
        };
        job.state = JobState::Running;
        job.attempts += 1;
        job.updated_ms = now_ms();
        self.set_live(&job);
        self.update_gauges();
        // Recorded, so that a restart knows this job was interrupted once already.
        if let Err(e) = self.store.put_job(&job).await {
            tracing::error!(job = job.id, error = %e, "cannot record the job as running");
        }
        let outcome = self.cook(&job).await;
        let finished = match outcome {
            Ok((glb, report)) => {
                let meta = ResultMeta {
                    job: job.id.clone(),
                    bytes: (glb.len() + report.len()) as u64,
                    created_ms: now_ms(),
                };
                match self.store.put_result(&job.key, &glb, &report, &meta).await {
                    Ok(()) => {
                        self.cache.lock().unwrap().touch(&job.key, meta.bytes);
                        job.state = JobState::Done;
                        job.progress = 1.0;
                        Ok(())
                    }
                    Err(e) => Err(JobError {
                        code: "storage".into(),
                        message: e.to_string(),
                    }),
                }
            }
            Err(e) => Err(e),
        };
        if let Err(e) = finished {
            tracing::warn!(job = job.id, error = e.message, "job failed");
            job.state = JobState::Failed;
            job.error = Some(e);
        }
        job.updated_ms = now_ms();
        metrics::counter!("occluder_jobs_finished_total", "state" => job.state.name()).increment(1);
        if let Err(e) = self.store.put_job(&job).await {
            tracing::error!(job = job.id, error = %e, "cannot store the finished job");
        }
        if job.state == JobState::Done {
            // A finished job's input is only needed to remake a broken result; it may go with
            // its result when the cache is full.
            self.evict().await;
        }
        self.active.lock().unwrap().remove(&job.key);
        self.live.lock().unwrap().remove(&job.id);
        self.update_gauges();
    }

    /// Ingests and cooks on a blocking thread; a panic fails this job only.
    async fn cook(self: &Arc<Self>, job: &Job) -> Result<(Vec<u8>, Vec<u8>), JobError> {
        let fail = |code: &str, message: String| JobError {
            code: code.into(),
            message,
        };
        let input = match self.store.input(&job.key).await {
            Ok(Some(input)) => input,
            Ok(None) => return Err(fail("input_missing", "the uploaded mesh is gone".into())),
            Err(e) => return Err(fail("storage", e.to_string())),
        };
        if job.kind == JobKind::Level {
            return self.bake_level(job, input).await;
        }
        let mut settings = self.settings.clone();
        match serde_json::from_value(job.settings.clone()) {
            Ok(cook) => settings.cook = cook,
            Err(e) => return Err(fail("bad_settings", e.to_string())),
        }
        let service = Arc::clone(self);
        let running = job.clone();
        let work = tokio::task::spawn_blocking(move || {
            let start = std::time::Instant::now();
            let (mesh, stats) = input.load().map_err(|e| fail("bad_mesh", e.to_string()))?;
            let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
            let progress = |stage: &str, done: f64| service.set_progress(&running, stage, done);
            let cooked = cook_with_progress(mesh, stats, ingest_ms, &settings, false, &progress)
                .map_err(|e| fail("gpu", e.to_string()))?;
            for (stage, ms) in &cooked.report.timings_ms.0 {
                metrics::histogram!("occluder_cook_stage_seconds", "stage" => stage.clone()).record(ms / 1e3);
            }
            metrics::histogram!("occluder_cook_seconds").record(cooked.report.timings_ms.total() / 1e3);
            let report = serde_json::to_vec_pretty(&cooked.report).expect("reports serialize");
            Ok((cooked.glb(), report))
        });
        match work.await {
            Ok(result) => result,
            Err(e) => Err(fail("panic", format!("the cook crashed: {e}"))),
        }
    }

    fn set_progress(&self, running: &Job, stage: &str, done: f64) {
        let mut job = running.clone();
        job.stage = Some(stage.to_string());
        job.progress = done;
        self.set_live(&job);
    }

    /// Bakes a level whose meshes are all keys: each is found in the store, or cooked from its
    /// kept upload (and filed under its key for the next level). The report holds the batches.
    async fn bake_level(self: &Arc<Self>, job: &Job, input: store::Input) -> Result<(Vec<u8>, Vec<u8>), JobError> {
        let fail = |code: &str, message: String| JobError {
            code: code.into(),
            message,
        };
        let mut settings = self.settings.clone();
        match serde_json::from_value::<LevelJobSettings>(job.settings.clone()) {
            Ok(level) => (settings.cook, settings.level) = (level.cook, level.level),
            Err(e) => return Err(fail("bad_settings", e.to_string())),
        }
        let level = crate::level::parse_manifest("the level", &input.bytes)
            .and_then(|m| crate::level::Level::from_manifest(m, |mesh| Some(crate::level::MeshRef::Key(mesh.into()))))
            .map_err(|e| fail("bad_level", e.to_string()))?;
        let service = Arc::clone(self);
        let running = job.clone();
        let runtime = tokio::runtime::Handle::current();
        // The bake is CPU-bound (rayon) between its store calls: it runs on a blocking thread.
        let work = tokio::task::spawn_blocking(move || {
            let progress = |done: usize, total: usize| {
                service.set_progress(&running, "meshes", 0.95 * done as f64 / total.max(1) as f64)
            };
            runtime.block_on(crate::level::bake(&level, &settings, service.store.as_ref(), &progress))
        });
        let baked = match work.await {
            Ok(Ok(baked)) => baked,
            Ok(Err(e @ crate::level::LevelError::Cache(_))) => return Err(fail("storage", e.to_string())),
            Ok(Err(e)) => return Err(fail("bad_level", e.to_string())),
            Err(e) => return Err(fail("panic", format!("the bake crashed: {e}"))),
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
                let active = self.active.lock().unwrap();
                cache.oldest(|k| active.contains_key(k))
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

/// Runs `workers` tasks that take jobs from the queue until `stop` turns true; each finishes the
/// job in hand first. Jobs still queued stay in the store for the next start.
pub async fn run_workers(
    service: Arc<Service>,
    queue: mpsc::UnboundedReceiver<String>,
    workers: usize,
    stop: watch::Receiver<bool>,
) {
    let queue = Arc::new(tokio::sync::Mutex::new(queue));
    let tasks: Vec<_> = (0..workers)
        .map(|_| {
            let (service, queue, mut stop) = (Arc::clone(&service), Arc::clone(&queue), stop.clone());
            tokio::spawn(async move {
                loop {
                    let next = tokio::select! {
                        id = async { queue.lock().await.recv().await } => id,
                        _ = stop.wait_for(|s| *s) => None,
                    };
                    match next {
                        Some(id) => service.run(id).await,
                        None => break,
                    }
                }
            })
        })
        .collect();
    for task in tasks {
        let _ = task.await;
    }
}

/// Runs the HTTP API (and, unless `api_only`, the workers) until SIGTERM or Ctrl-C. Prints
/// `listening on ADDR` once it accepts connections.
pub async fn serve(settings: Settings, api_only: bool) -> anyhow::Result<()> {
    use anyhow::Context;
    let metrics = metrics_exporter_prometheus::PrometheusBuilder::new()
        .set_buckets(&[
            0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
        ])
        .expect("buckets are not empty")
        .install_recorder()
        .context("cannot install the metrics recorder")?;
    let dir = settings.service.data_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let store: Arc<dyn Store> = Arc::new(store::sled::SledStore::open(&dir)?);
    let workers = settings.service.workers;
    let listen = settings.service.listen.clone();
    let (service, queue) = Service::start(store, settings).await?;
    let (stop, stopped) = watch::channel(false);
    let pool = (!api_only).then(|| tokio::spawn(run_workers(Arc::clone(&service), queue, workers, stopped.clone())));
    let app = api::router(api::AppState {
        service: Arc::clone(&service),
        metrics,
        shutdown: stopped,
    });
    let listener = tokio::net::TcpListener::bind(&listen)
        .await
        .with_context(|| format!("cannot listen on {listen}"))?;
    println!("listening on {}", listener.local_addr()?);
    let shutdown = async move {
        let mut term =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).expect("SIGTERM handler");
        tokio::select! {
            _ = term.recv() => {}
            _ = tokio::signal::ctrl_c() => {}
        }
        tracing::info!("shutting down: no new connections; running jobs finish, queued ones stay queued");
        let _ = stop.send(true);
    };
    axum::serve(listener, app).with_graceful_shutdown(shutdown).await?;
    if let Some(pool) = pool {
        let _ = pool.await;
    }
    service.store.flush().await?;
    Ok(())
}
