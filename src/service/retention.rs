//! What the service removes, and when: deletions' leftovers, expired data, stale temporary files, and the
//! sealing of data stored before objects were sealed.
//!
//! Deleting destroys an object's data key in the database first (in the deleting transaction); its sealed
//! files are removed after the commit, and the write-ahead log is checkpointed so no old page image of the
//! key survives there. If removing a file fails, or the process dies in between, the file is unreadable
//! (its key is gone) and the sweep at the next start removes it.

use std::collections::HashSet;
use std::path::{Component, Path};
use std::time::Duration;

use super::crypto::DataKey;
use super::sealed;
use super::state::AppState;
use super::store;

/// How often expired data is looked for.
const RETENTION_INTERVAL: Duration = Duration::from_secs(3600);

/// Removes what a deletion left on disk (paths relative to the data directory; a directory with all it
/// holds), then checkpoints the database's log. Failures are logged: the keys are already gone.
pub async fn finish_deletion(state: &AppState, paths: &[String]) {
    for relative in paths {
        remove_relative(&state.objects, relative).await;
    }
    match store::checkpoint(&state.writer).await {
        Ok(true) => {}
        Ok(false) => tracing::warn!("a reader kept the log checkpoint from completing; the next one will"),
        Err(e) => tracing::warn!(error = %e, "checkpointing the database log failed"),
    }
}

/// Removes the object or directory of objects `relative`; refuses paths that leave the data directory.
async fn remove_relative(objects: &store::objects::Objects, relative: &str) {
    let path = Path::new(relative);
    if !path.components().all(|c| matches!(c, Component::Normal(_))) {
        tracing::error!(path = relative, "refusing to remove a path outside the data directory");
        return;
    }
    if let Err(e) = objects.remove(relative).await {
        tracing::warn!(path = relative, error = %e, "could not remove deleted data (its key is gone)");
    }
}

/// Deletes documents and jobs created more than the retention period ago (with what they produced).
/// Returns how many documents and jobs went.
pub async fn purge_expired(state: &AppState, now_ms: i64) -> anyhow::Result<(usize, usize)> {
    let Some(retention) = state.config.retention else {
        return Ok((0, 0));
    };
    let cutoff = now_ms - retention.as_millis() as i64;
    let docs = store::documents::delete(&state.writer, store::documents::Which::CreatedBefore(cutoff), now_ms)
        .await?
        .unwrap_or_default();
    let mut tx = state.writer.0.begin().await?;
    let jobs = store::jobs::purge(&mut tx, store::jobs::JobSet::CreatedBefore(cutoff), "expired", now_ms).await?;
    tx.commit().await?;
    let n_docs = docs.documents.len();
    for doc in &docs.documents {
        store::audit::record(
            &state.writer,
            "retention",
            "document.expire",
            &format!("documents/{doc}"),
        )
        .await?;
    }
    let expired_jobs = docs.jobs.len() + jobs.jobs.len();
    for job in docs.jobs.iter().chain(&jobs.jobs) {
        store::audit::record(&state.writer, "retention", "job.expire", &format!("jobs/{job}")).await?;
    }
    let mut paths = docs.paths;
    paths.extend(jobs.paths);
    if !paths.is_empty() || expired_jobs > 0 {
        finish_deletion(state, &paths).await;
        tracing::info!(documents = n_docs, jobs = expired_jobs, "expired data deleted");
    }
    Ok((n_docs, expired_jobs))
}

/// Runs [`purge_expired`] now and every hour until shutdown.
pub fn spawn_retention(state: &AppState) -> tokio::task::JoinHandle<()> {
    let state = state.clone();
    tokio::spawn(async move {
        let mut shutdown = state.shutdown.clone();
        loop {
            if let Err(e) = purge_expired(&state, store::now_ms()).await {
                tracing::warn!(error = %format!("{e:#}"), "deleting expired data failed; will retry");
            }
            tokio::select! {
                _ = tokio::time::sleep(RETENTION_INTERVAL) => {}
                _ = super::state::stopped(&mut shutdown) => return,
            }
        }
    })
}

/// At the start of an API process on PostgreSQL: removes the objects of deleted documents and jobs whose
/// removal did not happen (the process died between the deleting commit and the removal). Objects under a
/// queued or running job are kept: a worker elsewhere may have stored its output and not yet recorded it.
/// Returns how many objects went.
pub async fn sweep_objects(state: &AppState) -> anyhow::Result<u64> {
    let r = sqlx::query(
        "DELETE FROM objects o WHERE
             (o.path >= 'documents/' AND o.path < 'documents0'
              AND NOT EXISTS (SELECT 1 FROM documents d WHERE d.deleted_at IS NULL AND d.path = o.path))
          OR (o.path >= 'jobs/' AND o.path < 'jobs0'
              AND NOT EXISTS (SELECT 1 FROM jobs j WHERE j.deleted_at IS NULL AND (
                      (j.bundle_path IS NOT NULL AND o.path >= j.bundle_path || '/' AND o.path < j.bundle_path || '0')
                   OR (j.state IN ('queued', 'running') AND o.path >= 'jobs/' || j.id || '-'
                       AND o.path < 'jobs/' || j.id || '.'))))",
    )
    .execute(&state.writer.0)
    .await?;
    Ok(r.rows_affected())
}

/// At start, before any worker runs: removes temporary files a crash left (`.part` files, `.tmp-*` job
/// directories) and the files of deleted documents and jobs whose removal did not happen. Returns how
/// many entries went.
pub async fn sweep(state: &AppState) -> anyhow::Result<usize> {
    let data = state.data_dir();
    let live_jobs: HashSet<String> = store::jobs::live_bundle_paths(&state.db).await?.into_iter().collect();
    let live_docs: HashSet<String> =
        sqlx::query_as::<_, (String,)>("SELECT path FROM documents WHERE deleted_at IS NULL")
            .fetch_all(&state.db)
            .await?
            .into_iter()
            .map(|(p,)| p)
            .collect();
    let mut removed = 0;
    for (dir, live) in [("jobs", &live_jobs), ("documents", &live_docs)] {
        let mut entries = match tokio::fs::read_dir(data.join(dir)).await {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e.into()),
        };
        while let Some(entry) = entries.next_entry().await? {
            let Ok(name) = entry.file_name().into_string() else {
                continue;
            };
            let relative = format!("{dir}/{name}");
            if live.contains(&relative) {
                continue;
            }
            // In jobs/, a queued or running job has no directory yet but its `.tmp-` one.
            remove_relative(&state.objects, &relative).await;
            tracing::info!(path = %relative, "removed a leftover (temporary or deleted)");
            removed += 1;
        }
    }
    Ok(removed)
}

/// At start: seals documents and jobs stored before sealing. A document's file is sealed under a new data
/// key and the plain file removed; a job's outputs likewise, every file in its output directory, and the
/// text hint of its options moved to its sealed options.
pub async fn seal_unsealed(state: &AppState) -> anyhow::Result<(usize, usize)> {
    let docs = store::documents::unsealed(&state.db).await?;
    for doc in &docs {
        let plain_path = state.data_dir().join(&doc.path);
        let bytes = tokio::fs::read(&plain_path).await?;
        let stored = sealed::store_document(&state.objects, &state.master_key, &doc.id, bytes.into(), None).await?;
        store::documents::set_sealed(
            &state.writer,
            &doc.id,
            &stored.path,
            &stored.content_mac,
            &stored.data_key,
        )
        .await?;
        if plain_path != state.data_dir().join(&stored.path) {
            tokio::fs::remove_file(&plain_path).await?;
        }
        tracing::info!(document = %doc.id, "sealed a document stored before sealing");
    }
    let jobs = store::jobs::unsealed(&state.db).await?;
    for job in &jobs {
        let id = job.id.to_string();
        let key = DataKey::generate();
        let wrapped = key.wrap(&state.master_key, &sealed::job_key_aad(&id))?;
        let options: eyekey_core::encoding::pipeline::EncodeOptions = serde_json::from_str(&job.options)?;
        let (clear, secret) = sealed::split_options(&options)?;
        let secret = secret
            .map(|s| key.seal(&s, &sealed::job_options_aad(&id)))
            .transpose()?;
        if let Some(dir) = &job.bundle_path {
            let dir = state.data_dir().join(dir);
            let (key, id) = (key.clone(), id.clone());
            tokio::task::spawn_blocking(move || seal_tree(&dir, &dir, &key, &id)).await??;
        }
        let summary = job
            .evaluation_summary
            .as_ref()
            .map(|text| key.seal(text.as_bytes(), &sealed::job_summary_aad(&id)))
            .transpose()?;
        let sealing = store::jobs::Sealing {
            data_key: &wrapped,
            options: &clear,
            sealed_options: secret.as_deref(),
            sealed_summary: summary.as_deref(),
        };
        store::jobs::set_sealed(&state.writer, job.id, &sealing).await?;
        tracing::info!(job = %id, "sealed a job stored before sealing");
    }
    if !docs.is_empty() || !jobs.is_empty() {
        store::checkpoint(&state.writer).await?;
    }
    Ok((docs.len(), jobs.len()))
}

/// Seals every plain file under `dir` as `<name>.sealed` (associated data naming it relative to `root`)
/// and removes the plain one.
fn seal_tree(root: &Path, dir: &Path, key: &DataKey, job_id: &str) -> anyhow::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            seal_tree(root, &path, key, job_id)?;
            continue;
        }
        let name = path.strip_prefix(root)?.to_string_lossy().replace('\\', "/");
        if name.ends_with(sealed::SUFFIX) {
            continue;
        }
        let plain = std::fs::read(&path)?;
        let target = path.with_file_name(format!("{}{}", entry.file_name().to_string_lossy(), sealed::SUFFIX));
        sealed::seal_to_file(&target, key, &sealed::job_file_aad(job_id, &name), &plain)?;
        std::fs::remove_file(&path)?;
    }
    Ok(())
}
