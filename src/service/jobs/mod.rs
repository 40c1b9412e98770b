//! Job execution: the worker pool, and the single worker step the tests drive by hand.
//!
//! A worker claims a job (see [`crate::service::store::jobs`]), loads and opens its inputs, and runs
//! [`eyekey_core::encoding::pipeline::render_job`] on a blocking thread (the pipeline spreads its work over the
//! rayon pool; tokio's worker threads never solve). Meanwhile the async side renews the lease (every third of
//! it, and at least every 500 ms), writes progress, and forwards a cancel request to the solver's flag.
//! The outputs exist in clear only in memory: each file, and the bundle's zip, is sealed under the job's data
//! key and stored as the objects `jobs/<job>-<attempt>/<name>.sealed` all at once (a directory renamed into
//! place on disk, one transaction in PostgreSQL), so a bundle is never visible half-written. A worker whose
//! success is refused (it lost the job, or the job was deleted meanwhile) removes its own output.
//!
//! Outcomes: success → `succeeded`; `PipelineError::Invalid` → `failed` at once (retrying cannot help);
//! any other error or a panic → back to `queued` while attempts remain, else `failed`; a cancel request →
//! `cancelled`. On shutdown, running jobs are cancelled and re-queued without counting the attempt.

pub mod bundle;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::task::JoinSet;

use super::crypto::DataKey;
use super::sealed;
use super::state::AppState;
use super::store::{self, jobs::JobRow, jobs::JobState};
use eyekey_core::encoding::pipeline::{render_job, JobSpec, PipelineError};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::profile::VisionProfile;

pub use super::store::ids::JobId;

/// An observer profile a job was created with, pinned to the version current at creation.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ObserverRef {
    /// The profile.
    pub profile_id: String,
    /// Its version.
    pub version: i64,
}

/// Runs `workers` worker loops until shutdown.
pub fn spawn_workers(state: &AppState, workers: usize) -> JoinSet<()> {
    let mut set = JoinSet::new();
    for n in 0..workers {
        let state = state.clone();
        set.spawn(async move { worker_loop(state, n).await });
    }
    set
}

async fn worker_loop(state: AppState, n: usize) {
    tracing::debug!(worker = n, "worker started");
    let mut shutdown = state.shutdown.clone();
    let mut backoff = Backoff::default();
    while !state.shutting_down() {
        let idle = match try_execute_next_job(&state).await {
            Ok(Some(claim)) if backoff.repeated(claim) => {
                // The same attempt of the same job again: the claim did not stick (the database refused the
                // write), so claiming at once would spin. Wait as after an error.
                tracing::warn!(worker = n, job = %claim.0, "a job was claimed twice at the same attempt; backing off");
                backoff.failed()
            }
            Ok(Some(_)) => {
                backoff.succeeded();
                continue;
            }
            Ok(None) => {
                backoff.succeeded();
                state.config.queue.poll_interval
            }
            Err(e) => {
                tracing::error!(worker = n, error = ?e, "worker step failed; backing off");
                backoff.failed()
            }
        };
        // Idle: wake when a job is queued (unless backing off), when shutdown begins, or after `idle` (to
        // notice jobs whose lease expired).
        let backing_off = backoff.failures > 0;
        tokio::select! {
            _ = state.job_queued.notified(), if !backing_off => {}
            _ = crate::service::state::stopped(&mut shutdown) => {}
            _ = tokio::time::sleep(idle) => {}
        }
    }
    tracing::debug!(worker = n, "worker stopped");
}

/// A worker's backoff after failed steps: 0.5 s, doubling to 30 s, reset by a step that did its work.
#[derive(Debug, Default)]
struct Backoff {
    failures: u32,
    last_claim: Option<(JobId, i64)>,
}

impl Backoff {
    /// Records a claim; true when it is the same job at the same attempt as the previous claim.
    fn repeated(&mut self, claim: (JobId, i64)) -> bool {
        self.last_claim.replace(claim) == Some(claim)
    }

    fn succeeded(&mut self) {
        self.failures = 0;
    }

    /// Records a failure; returns how long to wait.
    fn failed(&mut self) -> Duration {
        self.failures = self.failures.saturating_add(1);
        Duration::from_millis(500u64.saturating_mul(1 << (self.failures - 1).min(6))).min(Duration::from_secs(30))
    }
}

/// One worker step: ends jobs whose lease expired with no attempts left, claims the oldest claimable
/// job and runs it to the end of this attempt. Returns the job and attempt it claimed, `Ok(None)` when there
/// was nothing to do.
pub async fn try_execute_next_job(state: &AppState) -> anyhow::Result<Option<(JobId, i64)>> {
    if state.shutting_down() {
        return Ok(None);
    }
    let now = store::now_ms();
    for row in store::jobs::fail_exhausted(&state.writer, now).await? {
        tracing::warn!(job = %row.id, state = %row.state.as_str(), "lease expired with no attempts left");
        metrics::counter!("eyekey_jobs_finished_total", "state" => row.state.as_str()).increment(1);
        state.publish(&row);
    }
    let Some(job) = store::jobs::claim_next(&state.writer, &state.instance_id, state.config.queue.lease, now).await?
    else {
        return Ok(None);
    };
    let claim = (job.id, job.attempts);
    execute_claimed(state, job).await?;
    Ok(Some(claim))
}

/// Why a load of a job's inputs failed.
pub(crate) enum LoadError {
    /// The job cannot run (an input was deleted, or does not fit): fail without retrying.
    Fatal(String),
    /// Something that may pass on retry (I/O).
    Transient(anyhow::Error),
}

impl From<sqlx::Error> for LoadError {
    fn from(e: sqlx::Error) -> Self {
        Self::Transient(e.into())
    }
}

/// Why the solver was asked to stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stop {
    None,
    Cancel,
    Shutdown,
    LostLease,
}

/// What the solver thread hands back: the evaluation report, the bundle's file list and every output
/// sealed (name relative to the output directory, sealed bytes).
struct Solved {
    evaluation: serde_json::Value,
    files: Vec<bundle::BundleFile>,
    sealed: Vec<(String, Vec<u8>)>,
}

/// A running solver and the flags it shares with the async side.
struct Solver {
    handle: tokio::task::JoinHandle<Result<Solved, PipelineError>>,
    cancel: Arc<AtomicBool>,
    progress: Arc<AtomicU64>,
    started: Instant,
}

/// How a supervised attempt ended: the solver's result (or its panic), why it was stopped, and how long
/// it ran.
struct Finished {
    outcome: Result<Result<Solved, PipelineError>, tokio::task::JoinError>,
    stop: Stop,
    elapsed: Duration,
}

/// Runs a job this worker has just claimed (its `attempts` is this attempt's number).
pub async fn execute_claimed(state: &AppState, job: JobRow) -> anyhow::Result<()> {
    state.publish(&job);
    let attempt = job.attempts;
    tracing::info!(job = %job.id, attempt, "job started");
    let loaded = async {
        let key = sealed::job_key(&state.master_key, &job)
            .map_err(|e| LoadError::Fatal(format!("the job's data key: {e}")))?;
        Ok((load_spec(state, &job).await?, key))
    };
    let (spec, key) = match loaded.await {
        Ok(loaded) => loaded,
        Err(LoadError::Fatal(msg)) => return end(state, &job, JobState::Failed, Some(&msg)).await,
        Err(LoadError::Transient(e)) => return retry_or_fail(state, &job, &format!("{e:#}")).await,
    };
    // Renew the lease once before solving: it may have been cancelled, or lost, while claimed or loading.
    match store::jobs::heartbeat(&state.writer, job.id, attempt, state.config.queue.lease, 0.0).await? {
        None => return Ok(()),
        Some(true) => return end(state, &job, JobState::Cancelled, None).await,
        Some(false) => {}
    }
    let solver = spawn_solver(state, spec, key.clone(), job.id.to_string());
    let finished = supervise(state, &job, solver).await;
    finalise(state, &job, &key, finished).await
}

/// Starts the pipeline on a blocking thread; its outputs and the bundle's zip are sealed under `key`.
fn spawn_solver(state: &AppState, spec: JobSpec, key: DataKey, job_id: String) -> Solver {
    let cancel = Arc::new(AtomicBool::new(false));
    let progress = Arc::new(AtomicU64::new(0f64.to_bits()));
    let started = Instant::now();
    let handle = tokio::task::spawn_blocking({
        let (cancel, progress) = (cancel.clone(), progress.clone());
        let cache = state.transport_cache.clone();
        move || -> Result<Solved, PipelineError> {
            let report = |p: f64| progress.store(p.clamp(0.0, 1.0).to_bits(), Ordering::Relaxed);
            let rendered = render_job(&spec, &cache, &report, &cancel)?;
            let (files, sealed) = seal_outputs(&key, &job_id, &rendered.files)
                .map_err(|e| PipelineError::internal("sealing the outputs", e))?;
            let evaluation = serde_json::to_value(&rendered.evaluation)
                .map_err(|e| PipelineError::internal("recording the evaluation", e))?;
            Ok(Solved {
                evaluation,
                files,
                sealed,
            })
        }
    });
    Solver {
        handle,
        cancel,
        progress,
        started,
    }
}

/// The sealed objects of a job's output directory: each output (relative path, bytes) and the zip of its
/// bundle sealed under `key`, as `(<name>.sealed, sealed bytes)`.
pub type SealedOutputs = Vec<(String, Vec<u8>)>;

/// Seals a job's outputs (relative path, bytes) and the zip of its bundle under `key`; returns the bundle's
/// file list and the sealed objects to store under the job's output directory.
pub fn seal_outputs(
    key: &DataKey,
    job_id: &str,
    outputs: &[(String, Vec<u8>)],
) -> std::io::Result<(Vec<bundle::BundleFile>, SealedOutputs)> {
    let (files, zipped) = bundle::zip_bundle(outputs)?;
    let outputs = outputs.iter().map(|(n, b)| (n.as_str(), b.as_slice()));
    let mut sealed_files = Vec::new();
    for (name, plain) in outputs.chain([(bundle::ZIP_NAME, zipped.as_slice())]) {
        if !name.split('/').all(bundle::is_plain_file_name) {
            return Err(std::io::Error::other(format!("not a plain output name: {name}")));
        }
        let bytes = key
            .seal(plain, &sealed::job_file_aad(job_id, name))
            .map_err(std::io::Error::other)?;
        sealed_files.push((format!("{name}{}", sealed::SUFFIX), bytes));
    }
    Ok((files, sealed_files))
}

/// Waits for the solver while renewing the lease and recording progress, and asks it to stop on a
/// cancel request, a lost lease or shutdown.
async fn supervise(state: &AppState, job: &JobRow, solver: Solver) -> Finished {
    let Solver {
        mut handle,
        cancel,
        progress,
        started,
    } = solver;
    // Each tick renews the lease and records progress: every third of the lease, and at least twice a
    // second so progress streams stay lively (one small UPDATE per tick).
    let tick = (state.config.queue.lease / 3).clamp(Duration::from_millis(20), Duration::from_millis(500));
    let mut heartbeat = tokio::time::interval(tick);
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut shutdown = state.shutdown.clone();
    let mut watch = Watch {
        stop: Stop::None,
        published_progress: 0.0,
    };
    let outcome = loop {
        tokio::select! {
            r = &mut handle => break r,
            _ = heartbeat.tick() => watch.beat(state, job, &progress, &cancel).await,
            _ = crate::service::state::stopped(&mut shutdown), if watch.stop == Stop::None => {
                watch.stop = Stop::Shutdown;
                cancel.store(true, Ordering::Relaxed);
            }
        }
    };
    Finished {
        outcome,
        stop: watch.stop,
        elapsed: started.elapsed(),
    }
}

/// What the supervisor remembers between heartbeats.
struct Watch {
    stop: Stop,
    published_progress: f64,
}

impl Watch {
    /// One heartbeat: renews the lease with the current progress, forwards a cancel request or a lost
    /// lease to the solver, and publishes progress once it has moved by half a percent.
    async fn beat(&mut self, state: &AppState, job: &JobRow, progress: &AtomicU64, cancel: &AtomicBool) {
        let p = f64::from_bits(progress.load(Ordering::Relaxed));
        match store::jobs::heartbeat(&state.writer, job.id, job.attempts, state.config.queue.lease, p).await {
            Ok(Some(cancel_requested)) => {
                if cancel_requested && self.stop == Stop::None {
                    self.stop = Stop::Cancel;
                    cancel.store(true, Ordering::Relaxed);
                }
                if p - self.published_progress >= 0.005 {
                    self.published_progress = p;
                    let mut row = job.clone();
                    (row.state, row.progress) = (JobState::Running, p);
                    state.publish(&row);
                }
            }
            Ok(None) => {
                tracing::warn!(job = %job.id, attempt = job.attempts, "lost the lease; abandoning this attempt");
                self.stop = Stop::LostLease;
                cancel.store(true, Ordering::Relaxed);
            }
            // A failed heartbeat is retried on the next tick; the lease has slack for that.
            Err(e) => tracing::warn!(job = %job.id, error = %e, "heartbeat failed"),
        }
    }
}

/// How an attempt ended, decided from the solver's result and why it was stopped.
enum Outcome {
    /// The lease was lost: another worker owns the job now; record nothing.
    Abandoned,
    Succeeded(Solved),
    /// Stopped by shutdown: re-queue without counting the attempt.
    Interrupted,
    Cancelled,
    /// The job cannot succeed: fail without retrying.
    Invalid(PipelineError),
    /// Another error: retry while attempts remain.
    Errored(PipelineError),
    Panicked(tokio::task::JoinError),
}

impl Outcome {
    fn of(outcome: Result<Result<Solved, PipelineError>, tokio::task::JoinError>, stop: Stop) -> Self {
        match (outcome, stop) {
            (_, Stop::LostLease) => Self::Abandoned,
            (Ok(Ok(solved)), _) => Self::Succeeded(solved),
            (Ok(Err(_)) | Err(_), Stop::Shutdown) => Self::Interrupted,
            (Ok(Err(_)), Stop::Cancel) | (Ok(Err(PipelineError::Cancelled)), _) => Self::Cancelled,
            // Neither a bad input nor a target that cannot read its frames changes on a retry (the job's seed is
            // fixed).
            (Ok(Err(e @ (PipelineError::Invalid { .. } | PipelineError::TargetCannotRead { .. }))), _) => {
                Self::Invalid(e)
            }
            (Ok(Err(e)), _) => Self::Errored(e),
            (Err(join_error), _) => Self::Panicked(join_error),
        }
    }
}

/// Records how the attempt ended.
async fn finalise(state: &AppState, job: &JobRow, key: &DataKey, finished: Finished) -> anyhow::Result<()> {
    let outcome = Outcome::of(finished.outcome, finished.stop);
    let elapsed = finished.elapsed;
    match outcome {
        Outcome::Abandoned => Ok(()),
        Outcome::Succeeded(solved) => finalise_success(state, job, key, solved, elapsed).await,
        Outcome::Interrupted => requeue_on_shutdown(state, job).await,
        Outcome::Cancelled => finalise_cancelled(state, job, elapsed).await,
        Outcome::Invalid(e) => end(state, job, JobState::Failed, Some(&e.to_string())).await,
        Outcome::Errored(e) => schedule_retry(state, job, &e, elapsed).await,
        Outcome::Panicked(join_error) => finalise_panic(state, job, &join_error).await,
    }
}

/// Removes an attempt's output (a failure is only logged).
async fn discard(state: &AppState, dir: &str) {
    if let Err(e) = state.objects.remove(dir).await {
        tracing::warn!(dir, error = %e, "could not remove a job's output");
    }
}

/// Stores the output as `jobs/<job>-<attempt>/` (replacing what a crashed run of this same attempt left
/// there) and records the success, fenced by the attempt: a worker that lost the job meanwhile, or whose
/// job was deleted, removes its output and records nothing.
async fn finalise_success(
    state: &AppState,
    job: &JobRow,
    key: &DataKey,
    solved: Solved,
    elapsed: Duration,
) -> anyhow::Result<()> {
    let relative = format!("jobs/{}-{}", job.id, job.attempts);
    state.objects.write_dir(&relative, solved.sealed).await?;
    let success = store::jobs::Success {
        sealed_summary: summarise(&solved.evaluation)
            .map(|text| key.seal(text.as_bytes(), &sealed::job_summary_aad(&job.id.to_string())))
            .transpose()?,
        bundle_path: relative.clone(),
        bundle_files: serde_json::to_string(&solved.files)?,
        solve_ms: elapsed.as_millis() as i64,
    };
    if store::jobs::mark_succeeded(&state.writer, job.id, job.attempts, &success).await? {
        metrics::histogram!("eyekey_solve_duration_seconds", "outcome" => "succeeded").record(elapsed.as_secs_f64());
        metrics::counter!("eyekey_jobs_finished_total", "state" => "succeeded").increment(1);
        tracing::info!(job = %job.id, attempt = job.attempts, seconds = elapsed.as_secs_f64(), "job succeeded");
        publish_current(state, job.id).await;
    } else {
        tracing::warn!(job = %job.id, attempt = job.attempts, "finished after losing the job, or after it was deleted; result dropped");
        discard(state, &relative).await;
        // A deleted job that was running ends as cancelled (it stays a tombstone).
        end(state, job, JobState::Cancelled, None).await?;
    }
    Ok(())
}

/// Puts a job stopped by shutdown back in the queue without counting the attempt.
async fn requeue_on_shutdown(state: &AppState, job: &JobRow) -> anyhow::Result<()> {
    store::jobs::requeue(&state.writer, job.id, job.attempts, None, true).await?;
    tracing::info!(job = %job.id, "shutting down: job re-queued");
    publish_current(state, job.id).await;
    Ok(())
}

async fn finalise_cancelled(state: &AppState, job: &JobRow, elapsed: Duration) -> anyhow::Result<()> {
    metrics::histogram!("eyekey_solve_duration_seconds", "outcome" => "cancelled").record(elapsed.as_secs_f64());
    end(state, job, JobState::Cancelled, None).await
}

async fn schedule_retry(state: &AppState, job: &JobRow, e: &PipelineError, elapsed: Duration) -> anyhow::Result<()> {
    metrics::histogram!("eyekey_solve_duration_seconds", "outcome" => "error").record(elapsed.as_secs_f64());
    retry_or_fail(state, job, &e.to_string()).await
}

async fn finalise_panic(state: &AppState, job: &JobRow, join_error: &tokio::task::JoinError) -> anyhow::Result<()> {
    tracing::error!(job = %job.id, error = %join_error, "the encoder panicked");
    retry_or_fail(state, job, "the encoder crashed (internal error)").await
}

/// The part of the evaluation report stored with the job and shown in every job read: the headline
/// numbers of each section. Kept: top-level scalars, the `observers` scores, and in each section its
/// scalars and its `best` entry; dropped: per-person, per-configuration and per-step arrays and long
/// texts (the full report is `GET /v1/jobs/{id}/evaluation`). Keeps job reads small and fast.
pub fn summarise(report: &serde_json::Value) -> Option<String> {
    use serde_json::Value;
    fn short(v: &Value) -> bool {
        match v {
            Value::String(text) => text.len() <= 200,
            Value::Array(_) | Value::Object(_) => false,
            _ => true,
        }
    }
    let sections = report.as_object()?;
    let mut out = serde_json::Map::new();
    for (key, value) in sections {
        let kept = match value {
            Value::Object(fields) => Value::Object(
                fields
                    .iter()
                    .filter(|(name, v)| short(v) || (name.as_str() == "best" && v.is_object()))
                    .map(|(name, v)| (name.clone(), v.clone()))
                    .collect(),
            ),
            Value::Array(_) if key == "observers" => value.clone(),
            v if short(v) => v.clone(),
            _ => continue,
        };
        out.insert(key.clone(), kept);
    }
    serde_json::to_string(&Value::Object(out)).ok()
}

async fn publish_current(state: &AppState, id: JobId) {
    if let Ok(Some(row)) = store::jobs::get(&state.db, id).await {
        state.publish(&row);
    }
}

async fn end(state: &AppState, job: &JobRow, to: JobState, error: Option<&str>) -> anyhow::Result<()> {
    if store::jobs::mark_ended(&state.writer, job.id, job.attempts, to, error).await? {
        metrics::counter!("eyekey_jobs_finished_total", "state" => to.as_str()).increment(1);
        tracing::info!(job = %job.id, attempt = job.attempts, state = to.as_str(), error, "job ended");
        publish_current(state, job.id).await;
    }
    Ok(())
}

async fn retry_or_fail(state: &AppState, job: &JobRow, error: &str) -> anyhow::Result<()> {
    let message = format!("attempt {} of {}: {error}", job.attempts, job.max_attempts);
    if job.attempts < job.max_attempts {
        tracing::warn!(job = %job.id, error = %message, "job attempt failed; re-queued");
        store::jobs::requeue(&state.writer, job.id, job.attempts, Some(&message), false).await?;
        publish_current(state, job.id).await;
        state.job_queued.notify_one();
        Ok(())
    } else {
        end(state, job, JobState::Failed, Some(&message)).await
    }
}

async fn open_profile(state: &AppState, id: &str, version: i64, role: &str) -> Result<VisionProfile, LoadError> {
    let row = store::profiles::get_version(&state.db, id, version)
        .await?
        .ok_or_else(|| LoadError::Fatal(format!("the {role} profile {id} (version {version}) was deleted")))?;
    let plain = row
        .open(&state.master_key)
        .map_err(|e| LoadError::Fatal(format!("{role} profile {id}: {e}")))?;
    let text = String::from_utf8(plain).map_err(|_| LoadError::Fatal(format!("{role} profile {id} is not text")))?;
    VisionProfile::from_json(&text).map_err(|e| LoadError::Fatal(format!("{role} profile {id}: {e}")))
}

pub(crate) async fn load_image(state: &AppState, id: &str, role: &str) -> Result<image::RgbImage, LoadError> {
    let doc = store::documents::get(&state.db, id)
        .await?
        .ok_or_else(|| LoadError::Fatal(format!("the {role} document {id} was deleted")))?;
    let bytes = sealed::open_document(&state.objects, &state.master_key, &doc)
        .await
        .map_err(|e| match e {
            sealed::OpenError::Io(e) => LoadError::Transient(anyhow::anyhow!("reading the {role} document: {e}")),
            other => LoadError::Fatal(format!("the {role} document {id}: {other}")),
        })?;
    let max_pixels = state.config.limits.max_document_pixels;
    let role = role.to_string();
    tokio::task::spawn_blocking(move || {
        let format = super::images::format_of_content_type(Some(&doc.content_type))
            .map_err(|e| LoadError::Fatal(format!("{role} document: {e}")))?;
        let header = super::images::inspect(&bytes, format, max_pixels.max((doc.width * doc.height) as u64))
            .map_err(|e| LoadError::Fatal(format!("{role} document: {e}")))?;
        let image =
            super::images::decode(&bytes, &header).map_err(|e| LoadError::Fatal(format!("{role} document: {e}")))?;
        Ok(image.to_rgb8())
    })
    .await
    .map_err(|e| LoadError::Transient(e.into()))?
}

async fn load_spec(state: &AppState, job: &JobRow) -> Result<JobSpec, LoadError> {
    let display = store::displays::get(&state.db, &job.display_id)
        .await?
        .ok_or_else(|| LoadError::Fatal(format!("the display {} was deleted", job.display_id)))?;
    let geometry: DisplayGeometry = serde_json::from_str(&display.geometry)
        .map_err(|e| LoadError::Fatal(format!("stored display geometry: {e}")))?;
    let options =
        sealed::job_options(&state.master_key, job).map_err(|e| LoadError::Fatal(format!("stored options: {e:#}")))?;
    let observer_refs: Vec<ObserverRef> =
        serde_json::from_str(&job.observers).map_err(|e| LoadError::Fatal(format!("stored observers: {e}")))?;
    let target = open_profile(state, &job.profile_id, job.profile_version, "target").await?;
    let mut observers = Vec::with_capacity(observer_refs.len());
    for o in &observer_refs {
        observers.push(open_profile(state, &o.profile_id, o.version, "observer").await?);
    }
    let document = load_image(state, &job.document_id, "document").await?;
    let decoy = match &job.decoy_document_id {
        Some(id) => Some(load_image(state, id, "decoy").await?),
        None => None,
    };
    Ok(JobSpec {
        display: geometry,
        target,
        target_label: format!("profile {} version {}", job.profile_id, job.profile_version),
        observers,
        document,
        decoy,
        options,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_thirty_seconds_and_a_repeated_claim_is_noticed() {
        let mut b = Backoff::default();
        let waits: Vec<u64> = (0..9).map(|_| b.failed().as_millis() as u64).collect();
        assert_eq!(waits, [500, 1000, 2000, 4000, 8000, 16000, 30000, 30000, 30000]);
        b.succeeded();
        assert_eq!(b.failed(), Duration::from_millis(500));
        let job = JobId::new_v4();
        assert!(!b.repeated((job, 1)));
        assert!(b.repeated((job, 1)), "the same attempt twice");
        assert!(!b.repeated((job, 2)), "the next attempt is progress");
    }

    #[test]
    fn the_summary_keeps_headline_numbers_and_drops_long_lists() {
        let report = serde_json::json!({
            "metric": "ncc",
            "threshold": 0.5,
            "target": {"legibility": 0.9, "readable": true},
            "observers": [{"label": "o", "legibility": 0.1}],
            "population": {"count": 20, "readable_fraction": 0.0, "people": [{"legibility": 0.1}]},
            "camera": {"best": {"legibility": 0.2}, "tried": [{"legibility": 0.2}]},
            "key_sensitivity": {"optical_bits": 7.5, "optical_legibility": [[0.9]], "method": "x".repeat(500)},
        });
        let summary: serde_json::Value = serde_json::from_str(&summarise(&report).unwrap()).unwrap();
        assert_eq!(
            summary,
            serde_json::json!({
                "metric": "ncc",
                "threshold": 0.5,
                "target": {"legibility": 0.9, "readable": true},
                "observers": [{"label": "o", "legibility": 0.1}],
                "population": {"count": 20, "readable_fraction": 0.0},
                "camera": {"best": {"legibility": 0.2}},
                "key_sensitivity": {"optical_bits": 7.5},
            })
        );
        assert_eq!(summarise(&serde_json::Value::Null), None);
    }
}
