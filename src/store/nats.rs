//! The distributed store: NATS JetStream. Jobs go on a work-queue stream, on one subject per
//! owner (a lane), and a durable pull consumer per lane hands them to the workers, who take the
//! lanes in turn; job records and key claims live in KV buckets; inputs and results live in an
//! object store under their BLAKE3 keys, sealed as in the sled store.
//!
//! A worker keeps its job alive with in-progress acks. One that dies stops acking, and after
//! `ack_wait` the job is handed to another worker. The consumer hands a job out at most
//! `max_deliver + 1` times: the last time only to mark it failed, so that a mesh that keeps
//! killing workers ends as a failed job instead of vanishing.

use super::job::{Job, now_ms};
use super::{Claim, Delivery, Input, ResultMeta, Store, StoreError, StoreResult, Unwritten, seal, unseal};
use crate::config::ServiceSettings;
use async_nats::jetstream::{self, AckKind, consumer, kv, object_store, stream};
use async_trait::async_trait;
use futures_util::StreamExt;
use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tokio::io::AsyncReadExt;

const QUEUE_STREAM: &str = "OCCLUDER_JOBS";
/// Lane subjects are `occluder.jobs.LANE`.
const QUEUE_SUBJECTS: &str = "occluder.jobs.*";
/// Lane consumers are `occluder-workers-LANE`.
const CONSUMER: &str = "occluder-workers";
const JOBS_BUCKET: &str = "occluder-jobs";
const CLAIMS_BUCKET: &str = "occluder-claims";
const RESULTS_BUCKET: &str = "occluder-results";
const BLOBS_BUCKET: &str = "occluder-blobs";
/// How long a node waits for NATS at start (it may come up after the node).
const CONNECT_PATIENCE: Duration = Duration::from_secs(30);
/// How long a worker waits for the answer to a pull that does not wait for messages: the
/// server answers at once, and a pull it lost (as it restarted) is never answered.
const PULL_ANSWER: Duration = Duration::from_secs(10);
/// Bytes of verified results a node keeps in memory.
const RECENT_RESULT_BYTES: usize = 64 << 20;

pub struct NatsStore {
    jetstream: jetstream::Context,
    queue: stream::Stream,
    /// The consumer of each lane this node has taken from.
    consumers: tokio::sync::Mutex<HashMap<String, consumer::PullConsumer>>,
    /// The lane served last: the next turn goes to the one after it.
    last_lane: Mutex<String>,
    /// Woken by every job published, on any node.
    published: std::sync::Arc<tokio::sync::Notify>,
    ack_wait: Duration,
    max_deliver: i64,
    jobs: kv::Store,
    claims: kv::Store,
    results: kv::Store,
    blobs: object_store::ObjectStore,
    recent: Mutex<RecentResults>,
}

/// Results read lately, verified. A result never changes under its key, and each object-store
/// read costs a consumer on the server: cached GETs come from here.
#[derive(Default)]
struct RecentResults {
    blobs: HashMap<String, Vec<u8>>,
    order: VecDeque<String>,
    bytes: usize,
}

impl RecentResults {
    fn insert(&mut self, name: &str, payload: &[u8]) {
        if payload.len() > RECENT_RESULT_BYTES / 8 || self.blobs.contains_key(name) {
            return;
        }
        while self.bytes + payload.len() > RECENT_RESULT_BYTES {
            let Some(oldest) = self.order.pop_front() else { break };
            self.bytes -= self.blobs.remove(&oldest).map_or(0, |b| b.len());
        }
        self.bytes += payload.len();
        self.blobs.insert(name.to_string(), payload.to_vec());
        self.order.push_back(name.to_string());
    }

    fn remove(&mut self, name: &str) {
        if let Some(blob) = self.blobs.remove(name) {
            self.bytes -= blob.len();
            self.order.retain(|n| n != name);
        }
    }
}

fn backend(e: impl std::fmt::Display) -> StoreError {
    StoreError::Backend(format!("nats: {e}"))
}

fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> StoreResult<T> {
    serde_json::from_slice(bytes).map_err(|e| StoreError::Decode(e.to_string()))
}

impl NatsStore {
    /// Connects to `settings.nats_url` and creates the stream, consumer and buckets where they
    /// do not exist yet (every node does this; it is idempotent).
    pub async fn open(settings: &ServiceSettings) -> StoreResult<NatsStore> {
        let url = &settings.nats_url;
        let started = Instant::now();
        let client = loop {
            match connect_options(settings).await?.connect(url.as_str()).await {
                Ok(client) => break client,
                // Refused credentials or certificates do not get better by waiting.
                Err(e)
                    if !matches!(
                        e.kind(),
                        async_nats::ConnectErrorKind::Io
                            | async_nats::ConnectErrorKind::TimedOut
                            | async_nats::ConnectErrorKind::Dns
                    ) =>
                {
                    return Err(StoreError::Backend(format!("NATS at {url} refused this node: {e}")));
                }
                Err(e) if started.elapsed() < CONNECT_PATIENCE => {
                    tracing::warn!(url, error = %e, "NATS not reachable yet; retrying");
                    tokio::time::sleep(Duration::from_millis(500)).await;
                }
                Err(e) => return Err(StoreError::Backend(format!("cannot reach NATS at {url}: {e}"))),
            }
        };
        let jetstream = jetstream::new(client.clone());
        let queue = jetstream
            .get_or_create_stream(stream::Config {
                name: QUEUE_STREAM.into(),
                subjects: vec![QUEUE_SUBJECTS.into()],
                retention: stream::RetentionPolicy::WorkQueue,
                storage: stream::StorageType::File,
                // A job enqueued twice within this window (a retried publish) is queued once.
                duplicate_window: Duration::from_secs(120),
                ..Default::default()
            })
            .await
            .map_err(|e| backend(format!("cannot open the stream {QUEUE_STREAM}: {e}")))?;
        let published = std::sync::Arc::new(tokio::sync::Notify::new());
        let mut publications = client
            .subscribe(QUEUE_SUBJECTS)
            .await
            .map_err(|e| backend(format!("cannot watch {QUEUE_SUBJECTS}: {e}")))?;
        let wake = std::sync::Arc::clone(&published);
        tokio::spawn(async move {
            while publications.next().await.is_some() {
                wake.notify_waiters();
            }
        });
        let jobs = open_bucket(&jetstream, JOBS_BUCKET).await?;
        let claims = open_bucket(&jetstream, CLAIMS_BUCKET).await?;
        let results = open_bucket(&jetstream, RESULTS_BUCKET).await?;
        let blobs = jetstream
            .create_object_store(object_store::Config {
                bucket: BLOBS_BUCKET.into(),
                storage: stream::StorageType::File,
                ..Default::default()
            })
            .await
            .map_err(|e| backend(format!("cannot open the object store {BLOBS_BUCKET}: {e}")))?;
        Ok(NatsStore {
            jetstream,
            queue,
            consumers: Default::default(),
            last_lane: Mutex::default(),
            published,
            ack_wait: Duration::from_secs_f64(settings.ack_wait_s),
            max_deliver: settings.max_deliver as i64 + 1,
            jobs,
            claims,
            results,
            blobs,
            recent: Mutex::default(),
        })
    }

    async fn put_blob(&self, name: &str, payload: &[u8]) -> StoreResult<()> {
        let sealed = seal(payload);
        self.blobs.put(name, &mut sealed.as_slice()).await.map_err(backend)?;
        Ok(())
    }

    /// A result blob, from memory when it was read lately.
    async fn result_blob(&self, name: &str) -> StoreResult<Option<Vec<u8>>> {
        if let Some(payload) = self.recent.lock().unwrap().blobs.get(name) {
            return Ok(Some(payload.clone()));
        }
        let payload = self.blob(name).await?;
        if let Some(payload) = &payload {
            self.recent.lock().unwrap().insert(name, payload);
        }
        Ok(payload)
    }

    /// The sealed blob `name`; a broken seal deletes it and reads as missing.
    async fn blob(&self, name: &str) -> StoreResult<Option<Vec<u8>>> {
        let mut object = match self.blobs.get(name).await {
            Ok(object) => object,
            Err(e) if e.kind() == object_store::GetErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(backend(e)),
        };
        let mut sealed = Vec::new();
        object.read_to_end(&mut sealed).await.map_err(backend)?;
        match unseal(&sealed) {
            Some(payload) => Ok(Some(payload.to_vec())),
            None => {
                tracing::warn!(name, "blob failed its BLAKE3 check; deleted");
                metrics::counter!("occluder_corrupt_blobs_total").increment(1);
                self.delete_blob(name).await?;
                Ok(None)
            }
        }
    }

    async fn delete_blob(&self, name: &str) -> StoreResult<()> {
        self.recent.lock().unwrap().remove(name);
        match self.blobs.delete(name).await {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == object_store::DeleteErrorKind::NotFound => Ok(()),
            Err(e) => Err(backend(e)),
        }
    }

    /// Jobs on the queue (waiting or handed out) by lane, for the lanes that have any.
    async fn lane_counts(&self, subjects: &str) -> StoreResult<Vec<(String, usize)>> {
        let counts = self.queue.info_with_subjects(subjects).await.map_err(backend)?;
        let counts: Vec<(String, usize)> = counts
            .collect::<Vec<_>>()
            .await
            .into_iter()
            .collect::<Result<_, _>>()
            .map_err(backend)?;
        Ok(counts
            .into_iter()
            .filter_map(|(subject, count)| Some((subject.strip_prefix("occluder.jobs.")?.to_string(), count)))
            .filter(|(_, count)| *count > 0)
            .collect())
    }

    /// The pull consumer of `lane`, made on first use (by any node: it is durable).
    async fn lane_consumer(&self, lane: &str) -> StoreResult<consumer::PullConsumer> {
        let mut consumers = self.consumers.lock().await;
        if let Some(consumer) = consumers.get(lane) {
            return Ok(consumer.clone());
        }
        let name = format!("{CONSUMER}-{lane}");
        let consumer = self
            .queue
            .get_or_create_consumer(
                &name,
                consumer::pull::Config {
                    durable_name: Some(name.clone()),
                    filter_subject: lane_subject(lane),
                    ack_policy: consumer::AckPolicy::Explicit,
                    ack_wait: self.ack_wait,
                    max_deliver: self.max_deliver,
                    ..Default::default()
                },
            )
            .await
            .map_err(|e| backend(format!("cannot open the consumer {name}: {e}")))?;
        consumers.insert(lane.to_string(), consumer.clone());
        Ok(consumer)
    }

    /// A job waiting in one of the lanes, taken from the lane after the one served last.
    async fn take_in_turn(&self) -> StoreResult<Option<jetstream::Message>> {
        let mut lanes: Vec<String> = self
            .lane_counts(QUEUE_SUBJECTS)
            .await?
            .into_iter()
            .map(|(lane, _)| lane)
            .collect();
        lanes.sort();
        let last = self.last_lane.lock().unwrap().clone();
        let next = lanes.partition_point(|lane| *lane <= last);
        lanes.rotate_left(next);
        for lane in lanes {
            let consumer = self.lane_consumer(&lane).await?;
            // Without waiting: a lane whose jobs are all in workers' hands gives nothing.
            let mut batch = consumer.fetch().max_messages(1).messages().await.map_err(backend)?;
            let answer = tokio::time::timeout(PULL_ANSWER, batch.next())
                .await
                .map_err(|_| backend(format!("no answer to a pull from lane {lane} in {PULL_ANSWER:?}")))?;
            if let Some(message) = answer {
                *self.last_lane.lock().unwrap() = lane;
                return message.map(Some).map_err(backend);
            }
        }
        Ok(None)
    }

    /// Every key of a bucket.
    async fn keys(bucket: &kv::Store) -> StoreResult<Vec<String>> {
        bucket
            .keys()
            .await
            .map_err(backend)?
            .collect::<Vec<_>>()
            .await
            .into_iter()
            .collect::<Result<_, _>>()
            .map_err(backend)
    }

    async fn record<T: serde::de::DeserializeOwned>(bucket: &kv::Store, key: &str) -> StoreResult<Option<T>> {
        bucket.get(key).await.map_err(backend)?.map(|v| decode(&v)).transpose()
    }
}

/// A KV bucket keeping one revision per key. Its stream is made here, as a KV bucket's stream is
/// made: async-nats's `create_key_value` first reads account fields that nats-server 2.9 (the
/// Debian 12 package) does not send.
async fn open_bucket(jetstream: &jetstream::Context, name: &str) -> StoreResult<kv::Store> {
    let cannot = |e: &dyn std::fmt::Display| backend(format!("cannot open the bucket {name}: {e}"));
    jetstream
        .get_or_create_stream(stream::Config {
            name: format!("KV_{name}"),
            subjects: vec![format!("$KV.{name}.>")],
            max_messages_per_subject: 1,
            storage: stream::StorageType::File,
            allow_rollup: true,
            deny_delete: true,
            allow_direct: true,
            discard: stream::DiscardPolicy::New,
            ..Default::default()
        })
        .await
        .map_err(|e| cannot(&e))?;
    jetstream.get_key_value(name).await.map_err(|e| cannot(&e))
}

/// The lane of an owner's jobs: a subject token made from its name, which may hold any
/// character; `anyone` for jobs submitted without a token.
fn lane(owner: Option<&str>) -> String {
    match owner {
        Some(name) => blake3::hash(name.as_bytes()).to_hex()[..16].to_string(),
        None => "anyone".into(),
    }
}

fn lane_subject(lane: &str) -> String {
    format!("occluder.jobs.{lane}")
}

/// How a node signs in to NATS and checks its server: the credentials and the CA that the
/// settings name. A `tls://` URL or a CA requires TLS.
async fn connect_options(settings: &ServiceSettings) -> StoreResult<async_nats::ConnectOptions> {
    let read = |what: &str, path: &str| {
        std::fs::read_to_string(path)
            .map(|text| text.trim().to_string())
            .map_err(|e| StoreError::Backend(format!("cannot read {what} {path}: {e}")))
    };
    let mut options = async_nats::ConnectOptions::new();
    if !settings.nats_creds_file.is_empty() {
        options = options.credentials_file(&settings.nats_creds_file).await.map_err(|e| {
            StoreError::Backend(format!(
                "cannot read service.nats_creds_file {}: {e}",
                settings.nats_creds_file
            ))
        })?;
    } else if !settings.nats_nkey_file.is_empty() {
        options = options.nkey(read("service.nats_nkey_file", &settings.nats_nkey_file)?);
    } else if !settings.nats_user.is_empty() {
        let password = match settings.nats_password_file.as_str() {
            "" => String::new(),
            path => read("service.nats_password_file", path)?,
        };
        options = options.user_and_password(settings.nats_user.clone(), password);
    }
    if !settings.nats_ca_cert.is_empty() {
        options = options.add_root_certificates(settings.nats_ca_cert.clone().into());
    }
    let tls = !settings.nats_ca_cert.is_empty() || settings.nats_url.starts_with("tls://");
    Ok(options.require_tls(tls))
}

fn input_blob(key: &str) -> String {
    format!("input/{key}")
}

fn glb_blob(key: &str) -> String {
    format!("glb/{key}")
}

fn report_blob(key: &str) -> String {
    format!("report/{key}")
}

fn preview_blob(key: &str) -> String {
    format!("preview/{key}")
}

struct NatsDelivery {
    id: String,
    deliveries: u32,
    message: jetstream::Message,
}

#[async_trait]
impl Delivery for NatsDelivery {
    fn job_id(&self) -> &str {
        &self.id
    }

    fn deliveries(&self) -> u32 {
        self.deliveries
    }

    async fn keep_alive(&self) -> StoreResult<()> {
        self.message.ack_with(AckKind::Progress).await.map_err(backend)
    }

    async fn finish(&self) -> StoreResult<()> {
        self.message.double_ack().await.map_err(backend)
    }
}

#[async_trait]
impl Store for NatsStore {
    async fn put_job(&self, job: &Job) -> StoreResult<()> {
        let bytes = serde_json::to_vec(job).expect("jobs serialize");
        self.jobs.put(&job.id, bytes.into()).await.map_err(backend)?;
        Ok(())
    }

    async fn put_job_unless_ended(&self, job: &Job) -> StoreResult<Result<(), Unwritten>> {
        let bytes = serde_json::to_vec(job).expect("jobs serialize");
        // Another write between the read and this one, which checks the revision read: again.
        for _ in 0..8 {
            // No entry, or a delete marker.
            let entry = self.jobs.entry(&job.id).await.map_err(backend)?;
            let Some(entry) = entry.filter(|e| e.operation == kv::Operation::Put) else {
                return Ok(Err(Unwritten::Gone));
            };
            let stored: Job = decode(&entry.value)?;
            if stored.state.is_finished() {
                return Ok(Err(Unwritten::Ended(Box::new(stored))));
            }
            match self.jobs.update(&job.id, bytes.clone().into(), entry.revision).await {
                Err(e) if e.kind() == kv::UpdateErrorKind::WrongLastRevision => continue,
                written => return written.map(|_| Ok(())).map_err(backend),
            }
        }
        Err(backend(format!("the record of job {} keeps changing", job.id)))
    }

    async fn put_progress(&self, job: &Job) -> StoreResult<Result<(), Unwritten>> {
        self.put_job_unless_ended(job).await
    }

    async fn job(&self, id: &str) -> StoreResult<Option<Job>> {
        Self::record(&self.jobs, id).await
    }

    async fn jobs(&self) -> StoreResult<Vec<Job>> {
        let mut jobs = Vec::new();
        for id in Self::keys(&self.jobs).await? {
            jobs.extend(Self::record::<Job>(&self.jobs, &id).await?);
        }
        Ok(jobs)
    }

    async fn newest_jobs(&self, limit: usize) -> StoreResult<Vec<Job>> {
        // The bucket lists its keys in no order: all of them, but only the newest records.
        let mut ids = Self::keys(&self.jobs).await?;
        ids.sort_unstable_by(|a, b| b.cmp(a));
        let mut jobs = Vec::with_capacity(limit.min(ids.len()));
        for id in ids.iter().take(limit) {
            jobs.extend(Self::record::<Job>(&self.jobs, id).await?);
        }
        Ok(jobs)
    }

    async fn delete_job(&self, id: &str) -> StoreResult<()> {
        // Purged from the bucket's stream: a KV delete would leave a marker behind for each id.
        let subject = format!("{}{id}", self.jobs.prefix);
        self.jobs.stream.purge().filter(subject).await.map_err(backend)?;
        Ok(())
    }

    async fn claim(&self, key: &str, id: &str) -> StoreResult<Option<Claim>> {
        let claim = Claim {
            job: id.to_string(),
            since_ms: now_ms(),
        };
        // A claim can be released between a failed create and the read: try again then.
        for _ in 0..8 {
            match self.claims.create(key, claim.encode().into()).await {
                Ok(_) => return Ok(None),
                Err(e) if e.kind() == kv::CreateErrorKind::AlreadyExists => {
                    if let Some(held) = self.claims.get(key).await.map_err(backend)? {
                        let held = std::str::from_utf8(&held).ok().and_then(Claim::decode);
                        return held
                            .map(Some)
                            .ok_or_else(|| StoreError::Decode(format!("the claim on {key}")));
                    }
                }
                Err(e) => return Err(backend(e)),
            }
        }
        Err(StoreError::Backend(format!("the claim on {key} keeps changing hands")))
    }

    async fn release(&self, key: &str, id: &str) -> StoreResult<()> {
        let Some(entry) = self.claims.entry(key).await.map_err(backend)? else {
            return Ok(());
        };
        let held = std::str::from_utf8(&entry.value).ok().and_then(Claim::decode);
        if entry.operation == kv::Operation::Put && held.is_some_and(|claim| claim.job == id) {
            // Only this revision: a claim taken since by another job stays.
            if let Err(e) = self.claims.delete_expect_revision(key, Some(entry.revision)).await {
                tracing::debug!(key, error = %e, "claim changed hands before its release");
            }
        }
        Ok(())
    }

    async fn enqueue(&self, job: &Job) -> StoreResult<()> {
        let publish = jetstream::message::PublishMessage::build()
            .payload(job.id.clone().into())
            .message_id(&job.id);
        self.jetstream
            .send_publish(lane_subject(&lane(job.owner.as_deref())), publish)
            .await
            .map_err(backend)?
            .await
            .map_err(backend)?;
        Ok(())
    }

    async fn next_job(&self, wait: Duration) -> StoreResult<Option<Box<dyn Delivery>>> {
        let deadline = tokio::time::Instant::now() + wait;
        let message = loop {
            // Listening before looking, so that a job published in between still wakes it.
            let published = self.published.notified();
            tokio::pin!(published);
            published.as_mut().enable();
            if let Some(message) = self.take_in_turn().await? {
                break message;
            }
            if tokio::time::timeout_at(deadline, published).await.is_err() {
                return Ok(None);
            }
        };
        let deliveries = message.info().map_err(backend)?.delivered.max(1) as u32;
        let id = String::from_utf8_lossy(&message.payload).into_owned();
        Ok(Some(Box::new(NatsDelivery {
            id,
            deliveries,
            message,
        })))
    }

    async fn queue_depth(&self) -> StoreResult<usize> {
        let info = self.queue.get_info().await.map_err(backend)?;
        Ok(info.state.messages as usize)
    }

    async fn queued_for(&self, owner: Option<&str>) -> StoreResult<usize> {
        let lane = lane(owner);
        let counts = self.lane_counts(&lane_subject(&lane)).await?;
        Ok(counts.into_iter().map(|(_, count)| count).sum())
    }

    async fn put_input(&self, key: &str, input: &Input) -> StoreResult<()> {
        self.put_blob(&input_blob(key), &input.encode()).await
    }

    async fn input(&self, key: &str) -> StoreResult<Option<Input>> {
        let payload = self.blob(&input_blob(key)).await?;
        payload
            .map(|p| Input::decode(&p).ok_or_else(|| StoreError::Decode(format!("input {key}"))))
            .transpose()
    }

    async fn delete_input(&self, key: &str) -> StoreResult<()> {
        self.delete_blob(&input_blob(key)).await
    }

    async fn put_result(&self, key: &str, glb: &[u8], report: &[u8], meta: &ResultMeta) -> StoreResult<()> {
        self.put_blob(&glb_blob(key), glb).await?;
        self.put_blob(&report_blob(key), report).await?;
        // The meta goes last: a result is there once its meta is.
        let bytes = serde_json::to_vec(meta).expect("metas serialize");
        self.results.put(key, bytes.into()).await.map_err(backend)?;
        Ok(())
    }

    async fn result_glb(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.result_blob(&glb_blob(key)).await
    }

    async fn result_report(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.result_blob(&report_blob(key)).await
    }

    async fn result_meta(&self, key: &str) -> StoreResult<Option<ResultMeta>> {
        Self::record(&self.results, key).await
    }

    async fn put_preview(&self, key: &str, png: &[u8]) -> StoreResult<()> {
        self.put_blob(&preview_blob(key), png).await
    }

    async fn preview(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.result_blob(&preview_blob(key)).await
    }

    async fn delete_result(&self, key: &str) -> StoreResult<()> {
        self.results.delete(key).await.map_err(backend)?;
        self.delete_blob(&glb_blob(key)).await?;
        self.delete_blob(&report_blob(key)).await?;
        self.delete_blob(&preview_blob(key)).await
    }

    async fn results(&self) -> StoreResult<Vec<(String, ResultMeta)>> {
        let keys = Self::keys(&self.results).await?;
        let mut out = Vec::with_capacity(keys.len());
        for key in keys {
            if let Some(meta) = self.result_meta(&key).await? {
                out.push((key, meta));
            }
        }
        Ok(out)
    }

    /// JetStream acknowledges each write once it is stored: nothing is left to flush.
    async fn flush(&self) -> StoreResult<()> {
        Ok(())
    }
}
