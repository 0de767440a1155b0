//! The embedded store: one sled database with a tree per kind of record.

use super::{Input, ResultMeta, Store, StoreError, StoreResult, seal, unseal};
use crate::service::job::Job;
use async_trait::async_trait;
use std::path::Path;

pub struct SledStore {
    db: sled::Db,
    jobs: sled::Tree,
    inputs: sled::Tree,
    glbs: sled::Tree,
    reports: sled::Tree,
    metas: sled::Tree,
}

fn backend(e: impl std::fmt::Display) -> StoreError {
    StoreError::Backend(e.to_string())
}

impl SledStore {
    pub fn open(dir: &Path) -> StoreResult<SledStore> {
        let db = sled::open(dir).map_err(|e| StoreError::Backend(format!("cannot open {}: {e}", dir.display())))?;
        let tree = |name: &str| db.open_tree(name).map_err(backend);
        Ok(SledStore {
            jobs: tree("jobs")?,
            inputs: tree("inputs")?,
            glbs: tree("glbs")?,
            reports: tree("reports")?,
            metas: tree("result_meta")?,
            db,
        })
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

    async fn job(&self, id: &str) -> StoreResult<Option<Job>> {
        self.jobs.get(id).map_err(backend)?.map(|v| decode(&v)).transpose()
    }

    async fn unfinished_jobs(&self) -> StoreResult<Vec<Job>> {
        let mut out = Vec::new();
        for entry in self.jobs.iter() {
            let (_, value) = entry.map_err(backend)?;
            let job: Job = decode(&value)?;
            if !job.state.is_finished() {
                out.push(job);
            }
        }
        out.sort_by_key(|j| j.created_ms);
        Ok(out)
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

    async fn delete_result(&self, key: &str) -> StoreResult<()> {
        for tree in [&self.glbs, &self.reports, &self.metas] {
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
