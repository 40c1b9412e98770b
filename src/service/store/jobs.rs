//! The durable job queue and job records.
//!
//! A job is claimed atomically by one `UPDATE … RETURNING` that sets a lease; the owning worker renews
//! the lease with a heartbeat. Every write a worker makes after claiming is guarded by
//! `attempts = <its attempt>` and `state = 'running'`, so a worker that lost its lease (and whose job was
//! claimed again) can never overwrite the newer attempt's outcome: each job completes exactly once.

use std::time::Duration;

use serde::{Deserialize, Serialize};
use sqlx::any::{AnyTypeInfo, AnyValueRef};
use sqlx::encode::IsNull;
use sqlx::error::BoxDynError;
use sqlx::{Any, AnyPool, Database};

use super::ids::JobId;
use super::{now_ms, Cursor, Writer};

/// Where a job is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for a worker.
    Queued,
    /// A worker holds its lease.
    Running,
    /// Its bundle is available.
    Succeeded,
    /// It ended with an error (see `last_error`).
    Failed,
    /// It was cancelled.
    Cancelled,
}

impl JobState {
    /// Every state, in life order.
    pub const ALL: [JobState; 5] = [
        Self::Queued,
        Self::Running,
        Self::Succeeded,
        Self::Failed,
        Self::Cancelled,
    ];

    /// The database and wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Queued => "queued",
            Self::Running => "running",
            Self::Succeeded => "succeeded",
            Self::Failed => "failed",
            Self::Cancelled => "cancelled",
        }
    }

    /// Parses the database name.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// True for succeeded, failed and cancelled.
    pub fn is_terminal(self) -> bool {
        matches!(self, Self::Succeeded | Self::Failed | Self::Cancelled)
    }
}

/// Stored as its name (TEXT), on either backend.
impl sqlx::Type<Any> for JobState {
    fn type_info() -> AnyTypeInfo {
        <String as sqlx::Type<Any>>::type_info()
    }

    fn compatible(ty: &AnyTypeInfo) -> bool {
        <String as sqlx::Type<Any>>::compatible(ty)
    }
}

impl<'q> sqlx::Encode<'q, Any> for JobState {
    fn encode_by_ref(&self, buf: &mut <Any as Database>::ArgumentBuffer<'q>) -> Result<IsNull, BoxDynError> {
        <&str as sqlx::Encode<'q, Any>>::encode(self.as_str(), buf)
    }
}

impl<'r> sqlx::Decode<'r, Any> for JobState {
    fn decode(value: AnyValueRef<'r>) -> Result<Self, BoxDynError> {
        let text = <String as sqlx::Decode<'r, Any>>::decode(value)?;
        Self::parse(&text).ok_or_else(|| format!("not a job state: {text:?}").into())
    }
}

/// Inside the deleting transaction: cancels the queued jobs of a deleted display (with `reason` as their
/// last error) and asks the running ones to stop. Its finished jobs stay: they are the operator's record.
pub async fn stop_jobs_of_display(
    tx: &mut sqlx::AnyConnection,
    id: &str,
    reason: &str,
    now: i64,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET state = 'cancelled', last_error = $1, finished_at = $2, updated_at = $3
         WHERE display_id = $4 AND state = 'queued'",
    )
    .bind(reason)
    .bind(now)
    .bind(now)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    sqlx::query("UPDATE jobs SET cancel_requested = 1, updated_at = $1 WHERE display_id = $2 AND state = 'running'")
        .bind(now)
        .bind(id)
        .execute(&mut *tx)
        .await?;
    Ok(())
}

/// A flag stored as INTEGER 0/1 (the schema's type on both backends; sqlx's `Any` driver decodes no
/// integer as a `bool`).
#[derive(Clone, Copy, Debug, sqlx::Type)]
#[sqlx(transparent)]
pub struct IntFlag(pub i64);

impl From<IntFlag> for bool {
    fn from(f: IntFlag) -> bool {
        f.0 != 0
    }
}

/// A job row, as stored.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct JobRow {
    /// Id.
    pub id: JobId,
    /// Display it is for.
    pub display_id: String,
    /// Document shown.
    pub document_id: String,
    /// Decoy image, if any.
    pub decoy_document_id: Option<String>,
    /// Target profile.
    pub profile_id: String,
    /// Version of the target profile the job uses.
    pub profile_version: i64,
    /// JSON `[{"profile_id", "version"}]` of observer profiles.
    pub observers: String,
    /// Encoder method name.
    pub method: String,
    /// `EncodeOptions` JSON.
    pub options: String,
    /// State.
    pub state: JobState,
    /// Progress 0..=1.
    pub progress: f64,
    /// Claims so far.
    pub attempts: i64,
    /// Claims allowed.
    pub max_attempts: i64,
    /// Lease expiry (Unix ms) while running.
    pub lease_until: Option<i64>,
    /// Last heartbeat (Unix ms).
    pub heartbeat_at: Option<i64>,
    /// Worker holding the lease.
    pub worker_id: Option<String>,
    /// Last error message.
    pub last_error: Option<String>,
    /// Cancel was asked for.
    #[sqlx(try_from = "IntFlag")]
    pub cancel_requested: bool,
    /// Client's idempotency key.
    pub idempotency_key: Option<String>,
    /// SHA-256 of the canonical request, for idempotency checks.
    pub request_hash: String,
    /// Evaluation summary JSON of a job stored before summaries were sealed (until it is sealed at start).
    pub evaluation_summary: Option<String>,
    /// Evaluation summary JSON, sealed under the job's data key.
    pub sealed_summary: Option<Vec<u8>>,
    /// Output directory relative to the data directory.
    pub bundle_path: Option<String>,
    /// JSON list of the bundle files a display may fetch.
    pub bundle_files: Option<String>,
    /// Creation time.
    pub created_at: i64,
    /// First claim.
    pub started_at: Option<i64>,
    /// End time.
    pub finished_at: Option<i64>,
    /// Wall time of the successful solve, ms.
    pub solve_ms: Option<i64>,
    /// Last change.
    pub updated_at: i64,
    /// The data key its outputs and sealed options are sealed under, wrapped by the master key; `None` for a
    /// job stored before sealing (sealed at start) or deleted.
    pub data_key: Option<Vec<u8>>,
    /// The options that carry the document (its text hint), sealed under the job's data key.
    pub sealed_options: Option<Vec<u8>>,
}

const COLUMNS: &str = "id, display_id, document_id, decoy_document_id, profile_id, profile_version, observers, \
     method, options, state, progress, attempts, max_attempts, lease_until, heartbeat_at, worker_id, last_error, \
     cancel_requested, idempotency_key, request_hash, evaluation_summary, sealed_summary, bundle_path, bundle_files, created_at, \
     started_at, finished_at, solve_ms, updated_at, data_key, sealed_options";

/// A job to enqueue.
#[derive(Clone, Debug)]
pub struct NewJob {
    /// Id.
    pub id: JobId,
    /// Display.
    pub display_id: String,
    /// Document.
    pub document_id: String,
    /// Decoy document.
    pub decoy_document_id: Option<String>,
    /// Target profile.
    pub profile_id: String,
    /// Its version.
    pub profile_version: i64,
    /// Observers JSON.
    pub observers: String,
    /// Method name.
    pub method: String,
    /// Options JSON.
    pub options: String,
    /// Attempts allowed.
    pub max_attempts: i64,
    /// Idempotency key.
    pub idempotency_key: Option<String>,
    /// Canonical request digest (keyed).
    pub request_hash: String,
    /// Wrapped data key.
    pub data_key: Vec<u8>,
    /// Sealed options, if any carry the document.
    pub sealed_options: Option<Vec<u8>>,
}

/// What enqueueing did.
#[derive(Debug)]
pub enum Enqueued {
    /// A new job.
    Created(JobRow),
    /// The same key with the same request: the job created the first time.
    Existing(JobRow),
    /// The same key with a different request.
    KeyReused(JobRow),
}

/// Enqueues a job, honouring its idempotency key.
pub async fn enqueue(writer: &Writer, job: &NewJob) -> Result<Enqueued, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    // ON CONFLICT DO NOTHING on the unique key makes concurrent identical requests race safely: one
    // inserts, the others see no row returned and read the winner.
    let inserted = sqlx::query_as::<_, JobRow>(&format!(
        "INSERT INTO jobs (id, display_id, document_id, decoy_document_id, profile_id, profile_version, observers,
             method, options, state, max_attempts, idempotency_key, request_hash, created_at, updated_at,
             data_key, sealed_options)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, 'queued', $10, $11, $12, $13, $14, $15, $16)
         ON CONFLICT (idempotency_key) DO NOTHING
         RETURNING {COLUMNS}"
    ))
    .bind(job.id)
    .bind(&job.display_id)
    .bind(&job.document_id)
    .bind(&job.decoy_document_id)
    .bind(&job.profile_id)
    .bind(job.profile_version)
    .bind(&job.observers)
    .bind(&job.method)
    .bind(&job.options)
    .bind(job.max_attempts)
    .bind(&job.idempotency_key)
    .bind(&job.request_hash)
    .bind(now)
    .bind(now)
    .bind(&job.data_key)
    .bind(&job.sealed_options)
    .fetch_optional(pool)
    .await?;
    if let Some(row) = inserted {
        return Ok(Enqueued::Created(row));
    }
    let existing = sqlx::query_as::<_, JobRow>(&format!("SELECT {COLUMNS} FROM jobs WHERE idempotency_key = $1"))
        .bind(&job.idempotency_key)
        .fetch_one(pool)
        .await?;
    if existing.request_hash == job.request_hash {
        Ok(Enqueued::Existing(existing))
    } else {
        Ok(Enqueued::KeyReused(existing))
    }
}

/// One live (not deleted) job.
pub async fn get(pool: &AnyPool, id: JobId) -> Result<Option<JobRow>, sqlx::Error> {
    sqlx::query_as::<_, JobRow>(&format!(
        "SELECT {COLUMNS} FROM jobs WHERE id = $1 AND deleted_at IS NULL"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// Filters of a job listing.
#[derive(Clone, Debug, Default)]
pub struct JobFilter {
    /// Only jobs in this state.
    pub state: Option<JobState>,
    /// Only jobs for this display.
    pub display_id: Option<String>,
}

/// Jobs newest first.
pub async fn list(
    pool: &AnyPool,
    filter: &JobFilter,
    limit: u32,
    cursor: Option<&Cursor>,
) -> Result<Vec<JobRow>, sqlx::Error> {
    let (at, id) = cursor.map(|c| (c.created_at, c.id.as_str())).unwrap_or((i64::MAX, ""));
    sqlx::query_as::<_, JobRow>(&format!(
        "SELECT {COLUMNS} FROM jobs
         WHERE deleted_at IS NULL AND ($1 IS NULL OR state = $1) AND ($2 IS NULL OR display_id = $2)
           AND (created_at < $3 OR (created_at = $3 AND id < $4) OR $4 = '')
         ORDER BY created_at DESC, id DESC LIMIT $5"
    ))
    .bind(filter.state.map(JobState::as_str))
    .bind(filter.display_id.as_deref())
    .bind(at)
    .bind(id)
    .bind(limit as i64)
    .fetch_all(pool)
    .await
}

/// Asks a job to stop: a queued job is cancelled at once, a running one gets `cancel_requested` (its
/// worker stops between solver iterations). Returns the job after the change.
pub async fn request_cancel(writer: &Writer, id: JobId) -> Result<Option<JobRow>, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    sqlx::query_as::<_, JobRow>(&format!(
        "UPDATE jobs SET
             cancel_requested = CASE WHEN state IN ('queued', 'running') THEN 1 ELSE cancel_requested END,
             state = CASE WHEN state = 'queued' THEN 'cancelled' ELSE state END,
             finished_at = CASE WHEN state = 'queued' THEN $1 ELSE finished_at END,
             updated_at = $1
         WHERE id = $2 AND deleted_at IS NULL RETURNING {COLUMNS}"
    ))
    .bind(now)
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// Ends running jobs whose lease expired with no attempts left, or that were deleted (`failed`, or
/// `cancelled` if a cancel was asked for, as it is for every deleted job), and returns them.
pub async fn fail_exhausted(writer: &Writer, now: i64) -> Result<Vec<JobRow>, sqlx::Error> {
    let pool = &writer.0;
    sqlx::query_as::<_, JobRow>(&format!(
        "UPDATE jobs SET
             state = CASE WHEN cancel_requested = 1 THEN 'cancelled' ELSE 'failed' END,
             last_error = CASE WHEN cancel_requested = 1 THEN last_error
                 ELSE 'the worker stopped responding (lease expired) on attempt ' || attempts || ' of ' ||
                      max_attempts || COALESCE('; earlier error: ' || last_error, '') END,
             lease_until = NULL, finished_at = $1, updated_at = $1
         WHERE state = 'running' AND lease_until < $1
           AND (attempts >= max_attempts OR cancel_requested = 1 OR deleted_at IS NOT NULL)
         RETURNING {COLUMNS}"
    ))
    .bind(now)
    .fetch_all(pool)
    .await
}

/// Atomically claims the oldest claimable job: a queued one, or a running one whose lease expired
/// (its worker died) with attempts left. Sets the lease and counts the attempt.
pub async fn claim_next(
    writer: &Writer,
    worker_id: &str,
    lease: Duration,
    now: i64,
) -> Result<Option<JobRow>, sqlx::Error> {
    let pool = &writer.0;
    let lease_until = now + lease.as_millis() as i64;
    // One statement. On SQLite its write lock makes the select-and-update atomic; on PostgreSQL the
    // candidate row is locked with FOR UPDATE, and SKIP LOCKED lets concurrent workers pass over each
    // other's candidates instead of waiting on them. Either way two workers can never claim the same job.
    let lock = match writer.backend() {
        super::Backend::Sqlite => "",
        super::Backend::Postgres => "FOR UPDATE SKIP LOCKED",
    };
    sqlx::query_as::<_, JobRow>(&format!(
        "UPDATE jobs SET state = 'running', attempts = attempts + 1, lease_until = $1, heartbeat_at = $2,
             worker_id = $3, started_at = COALESCE(started_at, $2), updated_at = $2
         WHERE id = (
             SELECT id FROM jobs
             WHERE (state = 'queued' OR (state = 'running' AND lease_until < $2))
               AND attempts < max_attempts AND deleted_at IS NULL
             ORDER BY created_at, id LIMIT 1 {lock})
         RETURNING {COLUMNS}"
    ))
    .bind(lease_until)
    .bind(now)
    .bind(worker_id)
    .fetch_optional(pool)
    .await
}

/// Renews the lease of the caller's attempt and records progress. Returns `None` if the caller no
/// longer owns the job, else whether a cancel was asked for.
pub async fn heartbeat(
    writer: &Writer,
    id: JobId,
    attempt: i64,
    lease: Duration,
    progress: f64,
) -> Result<Option<bool>, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    let row: Option<(i64,)> = sqlx::query_as(
        "UPDATE jobs SET lease_until = $1, heartbeat_at = $2,
             progress = CASE WHEN progress > $3 THEN progress ELSE $3 END, updated_at = $2
         WHERE id = $4 AND attempts = $5 AND state = 'running'
         RETURNING cancel_requested",
    )
    .bind(now + lease.as_millis() as i64)
    .bind(now)
    .bind(progress.clamp(0.0, 1.0))
    .bind(id)
    .bind(attempt)
    .fetch_optional(pool)
    .await?;
    Ok(row.map(|(c,)| c != 0))
}

/// What a finished bundle looks like in the row.
#[derive(Clone, Debug)]
pub struct Success {
    /// Evaluation summary JSON, sealed under the job's data key.
    pub sealed_summary: Option<Vec<u8>>,
    /// Output directory, relative to the data directory.
    pub bundle_path: String,
    /// Bundle files JSON.
    pub bundle_files: String,
    /// Solve wall time.
    pub solve_ms: i64,
}

/// Marks the caller's attempt succeeded. False if it no longer owned the job, or the job was deleted.
pub async fn mark_succeeded(writer: &Writer, id: JobId, attempt: i64, s: &Success) -> Result<bool, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    let r = sqlx::query(
        "UPDATE jobs SET state = 'succeeded', progress = 1, sealed_summary = $1, bundle_path = $2,
             bundle_files = $3, solve_ms = $4, lease_until = NULL, finished_at = $5, updated_at = $5
         WHERE id = $6 AND attempts = $7 AND state = 'running' AND deleted_at IS NULL",
    )
    .bind(&s.sealed_summary)
    .bind(&s.bundle_path)
    .bind(&s.bundle_files)
    .bind(s.solve_ms)
    .bind(now)
    .bind(id)
    .bind(attempt)
    .execute(pool)
    .await?;
    Ok(r.rows_affected() == 1)
}

/// Ends the caller's attempt in `failed` or `cancelled`. False if it no longer owned the job.
pub async fn mark_ended(
    writer: &Writer,
    id: JobId,
    attempt: i64,
    state: JobState,
    error: Option<&str>,
) -> Result<bool, sqlx::Error> {
    let pool = &writer.0;
    debug_assert!(matches!(state, JobState::Failed | JobState::Cancelled));
    let now = now_ms();
    let r = sqlx::query(
        "UPDATE jobs SET state = $1, last_error = COALESCE($2, last_error), lease_until = NULL,
             finished_at = $3, updated_at = $3
         WHERE id = $4 AND attempts = $5 AND state = 'running'",
    )
    .bind(state.as_str())
    .bind(error)
    .bind(now)
    .bind(id)
    .bind(attempt)
    .execute(pool)
    .await?;
    Ok(r.rows_affected() == 1)
}

/// Puts the caller's attempt back in the queue. With `refund` the attempt is not counted (the server
/// is shutting down; the job did nothing wrong). False if it no longer owned the job.
pub async fn requeue(
    writer: &Writer,
    id: JobId,
    attempt: i64,
    error: Option<&str>,
    refund: bool,
) -> Result<bool, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    let r = sqlx::query(
        "UPDATE jobs SET state = 'queued', attempts = attempts - $1, last_error = COALESCE($2, last_error),
             lease_until = NULL, worker_id = NULL, progress = 0, updated_at = $3
         WHERE id = $4 AND attempts = $5 AND state = 'running'",
    )
    .bind(i64::from(refund))
    .bind(error)
    .bind(now)
    .bind(id)
    .bind(attempt)
    .execute(pool)
    .await?;
    Ok(r.rows_affected() == 1)
}

/// Number of live jobs in each state.
pub async fn count_by_state(pool: &AnyPool) -> Result<Vec<(JobState, i64)>, sqlx::Error> {
    let rows: Vec<(String, i64)> =
        sqlx::query_as("SELECT state, COUNT(*) FROM jobs WHERE deleted_at IS NULL GROUP BY state")
            .fetch_all(pool)
            .await?;
    Ok(JobState::ALL
        .into_iter()
        .map(|s| (s, rows.iter().find(|(n, _)| n == s.as_str()).map_or(0, |(_, c)| *c)))
        .collect())
}

/// Which jobs a [`purge`] deletes.
#[derive(Clone, Copy, Debug)]
pub enum JobSet<'a> {
    /// This one.
    One(JobId),
    /// Every job that showed this document (or used it as the decoy).
    OfDocument(&'a str),
    /// Every job whose target or one of whose observers is this profile.
    OfProfile(&'a str),
    /// Every job created before this time (Unix ms): expiry.
    CreatedBefore(i64),
}

/// What a purge leaves to remove from the disk (relative to the data directory) and which jobs it took.
#[derive(Clone, Debug, Default)]
pub struct Purged {
    /// Output directories.
    pub paths: Vec<String>,
    /// Ids of the deleted jobs.
    pub jobs: Vec<String>,
}

/// Inside a transaction: deletes jobs. A queued one is cancelled, a running one asked to stop (its worker
/// drops its output: [`mark_succeeded`] refuses a deleted job); every one loses its data key, sealed
/// options, evaluation summary and bundle listing and is kept as a tombstone (its audit trail refers to
/// it). Returns the output directories to remove once the transaction has committed.
pub async fn purge(
    tx: &mut sqlx::AnyConnection,
    set: JobSet<'_>,
    reason: &str,
    now: i64,
) -> Result<Purged, sqlx::Error> {
    let (one, document, profile, before) = match set {
        JobSet::One(id) => (Some(id.to_string()), None, None, None),
        JobSet::OfDocument(d) => (None, Some(d), None, None),
        JobSet::OfProfile(p) => (None, None, Some(p), None),
        JobSet::CreatedBefore(t) => (None, None, None, Some(t)),
    };
    // An observer's profile id, from the observers' JSON array, in each backend's JSON functions.
    let observer = match super::Backend::of_connection(tx) {
        super::Backend::Sqlite => {
            "EXISTS (SELECT 1 FROM json_each(jobs.observers) WHERE json_extract(value, '$.profile_id') = $3)"
        }
        super::Backend::Postgres => {
            "EXISTS (SELECT 1 FROM jsonb_array_elements(jobs.observers::jsonb) o WHERE o ->> 'profile_id' = $3)"
        }
    };
    // A NULL parameter makes its comparison false, so exactly one line of the condition selects.
    let rows: Vec<(String, Option<String>)> = sqlx::query_as(&format!(
        "SELECT id, bundle_path FROM jobs WHERE deleted_at IS NULL AND (
             id = $1
             OR document_id = $2 OR decoy_document_id = $2
             OR profile_id = $3
             OR {observer}
             OR created_at < $4)"
    ))
    .bind(&one)
    .bind(document)
    .bind(profile)
    .bind(before)
    .fetch_all(&mut *tx)
    .await?;
    let mut purged = Purged::default();
    for (id, bundle_path) in rows {
        sqlx::query(
            "UPDATE jobs SET
                 cancel_requested = CASE WHEN state IN ('queued', 'running') THEN 1 ELSE cancel_requested END,
                 last_error = CASE WHEN state = 'queued' THEN $1 ELSE last_error END,
                 finished_at = CASE WHEN state = 'queued' THEN $2 ELSE finished_at END,
                 state = CASE WHEN state = 'queued' THEN 'cancelled' ELSE state END,
                 deleted_at = $2, data_key = NULL, sealed_options = NULL, evaluation_summary = NULL,
                 sealed_summary = NULL,
                 bundle_path = NULL, bundle_files = NULL, updated_at = $2
             WHERE id = $3",
        )
        .bind(reason)
        .bind(now)
        .bind(&id)
        .execute(&mut *tx)
        .await?;
        purged.paths.extend(bundle_path);
        purged.jobs.push(id);
    }
    Ok(purged)
}

/// Live jobs stored before sealing (no data key yet).
pub async fn unsealed(pool: &AnyPool) -> Result<Vec<JobRow>, sqlx::Error> {
    sqlx::query_as::<_, JobRow>(&format!(
        "SELECT {COLUMNS} FROM jobs WHERE data_key IS NULL AND deleted_at IS NULL"
    ))
    .fetch_all(pool)
    .await
}

/// What sealing a job stored before sealing gives it.
#[derive(Clone, Debug)]
pub struct Sealing<'a> {
    /// Wrapped data key.
    pub data_key: &'a [u8],
    /// The options' clear part.
    pub options: &'a str,
    /// The options' sealed part.
    pub sealed_options: Option<&'a [u8]>,
    /// The sealed evaluation summary.
    pub sealed_summary: Option<&'a [u8]>,
}

/// Records that a job stored before sealing is now sealed: its data key, options split into clear and
/// sealed parts, its summary sealed.
pub async fn set_sealed(writer: &Writer, id: JobId, s: &Sealing<'_>) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET data_key = $1, options = $2, sealed_options = $3, sealed_summary = $4, evaluation_summary = NULL
         WHERE id = $5 AND deleted_at IS NULL",
    )
    .bind(s.data_key)
    .bind(s.options)
    .bind(s.sealed_options)
    .bind(s.sealed_summary)
    .bind(id)
    .execute(&writer.0)
    .await?;
    Ok(())
}

/// Output directories (relative to the data directory) of every live job, for sweeping the ones nobody
/// refers to.
pub async fn live_bundle_paths(pool: &AnyPool) -> Result<Vec<String>, sqlx::Error> {
    let rows: Vec<(String,)> =
        sqlx::query_as("SELECT bundle_path FROM jobs WHERE deleted_at IS NULL AND bundle_path IS NOT NULL")
            .fetch_all(pool)
            .await?;
    Ok(rows.into_iter().map(|(p,)| p).collect())
}
