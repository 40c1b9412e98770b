//! `/v1/jobs`: encoding jobs (operator only): create (idempotent), read, list, cancel, delete, follow.
//!
//! A job gets a data key of its own at creation; its outputs, and the options that carry the document (its
//! text hint), are sealed under it.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use futures::Stream;
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast::error::RecvError;
use uuid::Uuid;

use super::displays::{resolvability_warnings, stored_geometry};
use super::{id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::crypto::{DataKey, MasterKey};
use crate::service::error::{ApiError, ApiJson, ApiPath, ApiQuery, ErrorBody};
use crate::service::jobs::bundle::BundleFile;
use crate::service::jobs::ObserverRef;
use crate::service::sealed;
use crate::service::state::{AppState, JobEvent};
use crate::service::store::ids::JobId;
use crate::service::store::jobs::{Enqueued, JobFilter, JobRow, JobState, NewJob};
use crate::service::store::{self, to_time};
use eyekey_core::encoding::footprint::footprint;
use eyekey_core::encoding::pipeline::{EncodeOptions, Method, PipelineError};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::resolvability::Resolvability;

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/jobs", get(list_jobs).post(create_job))
        .route("/v1/jobs/{id}", get(get_job).delete(delete_job))
        .route("/v1/jobs/{id}/cancel", post(cancel_job))
        .route("/v1/jobs/{id}/events", get(job_events))
}

/// Body of a job creation.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateJob {
    /// The display the frames are for.
    pub display_id: Uuid,
    /// The document to show.
    pub document_id: Uuid,
    /// The enrolled person who must read it (its current version is used and recorded).
    pub profile_id: Uuid,
    /// Encoder options; every field has a default.
    #[serde(default)]
    pub options: Option<EncodeOptions>,
    /// Enrolled people who must not read it (representative observers), at most 16.
    #[serde(default)]
    #[schema(max_items = 16)]
    pub observer_profile_ids: Vec<Uuid>,
    /// An image to show everybody else instead (same aspect ratio as the document).
    #[serde(default)]
    pub decoy_document_id: Option<Uuid>,
}

/// Times of a job.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JobTimings {
    /// Creation.
    pub created_at: DateTime<Utc>,
    /// First claim by a worker.
    pub started_at: Option<DateTime<Utc>>,
    /// End (any terminal state).
    pub finished_at: Option<DateTime<Utc>>,
    /// Wall time of the successful attempt's solve, seconds.
    pub solve_seconds: Option<f64>,
}

/// A job as the operator sees it.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JobView {
    /// Id.
    pub id: Uuid,
    /// State.
    pub state: JobState,
    /// Progress of the current attempt, 0–1.
    pub progress: f64,
    /// Attempts so far.
    pub attempts: i64,
    /// Attempts allowed.
    pub max_attempts: i64,
    /// A cancel was asked for (takes effect between solver iterations).
    pub cancel_requested: bool,
    /// Display.
    pub display_id: Uuid,
    /// Document.
    pub document_id: Uuid,
    /// Decoy document.
    pub decoy_document_id: Option<Uuid>,
    /// Target profile.
    pub profile_id: Uuid,
    /// Version of the target profile this job uses.
    pub profile_version: i64,
    /// Observer profiles and the versions this job uses.
    pub observers: Vec<ObserverRef>,
    /// Encoder.
    pub method: Method,
    /// Options in full (defaults filled in, and the seed the job draws its decoys, noise and kernels from:
    /// fresh for every job unless the request gave one; kept sealed, shown only to operators).
    pub options: EncodeOptions,
    /// Last error (of the final attempt when failed, else of an earlier retried attempt).
    pub last_error: Option<String>,
    /// The failure's code, where it has one: `target_cannot_read` when the target does not read its frames even
    /// with the decoys as light as the target guard takes them (`last_error` says how far it was and what would
    /// help). No frames are delivered then.
    pub error_code: Option<String>,
    /// Headline numbers of the evaluation report once succeeded: target, observers, and each section's
    /// scalars and best case (the full report: `/v1/jobs/{id}/evaluation`).
    #[schema(value_type = Option<Object>)]
    pub evaluation_summary: Option<serde_json::Value>,
    /// Files of the frame bundle once succeeded.
    pub bundle_files: Option<Vec<BundleFile>>,
    /// Times.
    pub timings: JobTimings,
    /// Problems that do not stop the job: when diffraction leaves the display's views unresolved (some band
    /// has resolvability M < 1, see the display's `resolvability`), one line naming the worst band. The job
    /// still runs, but the target may not see the intended image.
    pub warnings: Vec<String>,
}

/// A page of jobs.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JobList {
    /// Jobs, newest first.
    pub items: Vec<JobView>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

/// Filters and paging of a job listing.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct JobListQuery {
    /// Only jobs in this state.
    pub state: Option<JobState>,
    /// Only jobs for this display.
    pub display_id: Option<Uuid>,
    /// Items per page (1–200, default 50).
    #[param(minimum = 1, maximum = 200)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page, as the service returned it: `<created_at>.<id>` of the last item
    /// seen.
    #[param(pattern = r"^[0-9]{1,18}\.[0-9a-z-]{1,36}$")]
    pub cursor: Option<String>,
}

fn parse_id(s: &str) -> Uuid {
    s.parse().unwrap_or_default()
}

impl JobView {
    /// The view of a stored job, with its display's `warnings` (its sealed options opened with `master`).
    fn new(master: &MasterKey, r: &JobRow, warnings: Vec<String>) -> Result<Self, ApiError> {
        let internal = |what: &str, e: serde_json::Error| ApiError::Internal(anyhow::anyhow!("stored {what}: {e}"));
        let options = sealed::job_options(master, r).map_err(|e| e.context("stored options"))?;
        Ok(Self {
            id: r.id.as_uuid(),
            state: r.state,
            progress: r.progress,
            attempts: r.attempts,
            max_attempts: r.max_attempts,
            cancel_requested: r.cancel_requested,
            display_id: parse_id(&r.display_id),
            document_id: parse_id(&r.document_id),
            decoy_document_id: r.decoy_document_id.as_deref().map(parse_id),
            profile_id: parse_id(&r.profile_id),
            profile_version: r.profile_version,
            observers: serde_json::from_str(&r.observers).map_err(|e| internal("observers", e))?,
            method: options.method,
            options,
            last_error: r.last_error.clone(),
            error_code: r
                .last_error
                .as_deref()
                .and_then(|e| e.split_once(':'))
                .map(|(code, _)| code)
                .filter(|code| *code == eyekey_core::encoding::pipeline::TARGET_CANNOT_READ)
                .map(str::to_string),
            evaluation_summary: sealed::job_summary(master, r).map_err(|e| e.context("stored summary"))?,
            bundle_files: r.bundle_files.as_deref().and_then(|s| serde_json::from_str(s).ok()),
            timings: JobTimings {
                created_at: to_time(r.created_at),
                started_at: r.started_at.map(to_time),
                finished_at: r.finished_at.map(to_time),
                solve_seconds: r.solve_ms.map(|ms| ms as f64 / 1000.0),
            },
            warnings,
        })
    }
}

/// The resolvability warnings of a display's stored geometry (`DisplayGeometry` JSON).
fn geometry_warnings(geometry_json: &str) -> Result<Vec<String>, ApiError> {
    let geometry = stored_geometry(geometry_json)?;
    Ok(resolvability_warnings(&Resolvability::of(&geometry)))
}

/// The warnings of the display a job is for (deleted displays included; none if it is unknown). A display's
/// geometry never changes, so they are computed once per display and kept in the state: job reads, a hot
/// path, cost no query for them.
async fn display_warnings(state: &AppState, display_id: &str) -> Result<Vec<String>, ApiError> {
    if let Some(w) = state
        .display_warnings
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .get(display_id)
    {
        return Ok(w.clone());
    }
    let warnings = match store::displays::geometry(&state.db, display_id).await? {
        Some(json) => geometry_warnings(&json)?,
        None => return Ok(Vec::new()),
    };
    let mut cache = state.display_warnings.lock().unwrap_or_else(|e| e.into_inner());
    cache.insert(display_id.to_string(), warnings.clone());
    Ok(warnings)
}

/// The pipeline's own range checks, reported with the offending field.
fn check_options(o: &EncodeOptions) -> Result<(), ApiError> {
    o.validate().map_err(|e| match e {
        PipelineError::Invalid { field, reason } => ApiError::invalid(&field, &reason),
        other => ApiError::Invalid {
            field: Some("options".into()),
            message: other.to_string(),
        },
    })
}

fn idempotency_key(headers: &HeaderMap) -> Result<Option<String>, ApiError> {
    let Some(v) = headers.get("idempotency-key") else {
        return Ok(None);
    };
    let key = v
        .to_str()
        .ok()
        .map(str::trim)
        .filter(|k| !k.is_empty() && k.len() <= 200 && k.bytes().all(|b| b.is_ascii_graphic()));
    match key {
        Some(k) => Ok(Some(k.to_string())),
        None => Err(ApiError::invalid(
            "Idempotency-Key",
            "the Idempotency-Key header must be 1 to 200 visible ASCII characters",
        )),
    }
}

/// Create a job.
///
/// With an `Idempotency-Key` header, repeating the same request returns the job created the first time
/// (200 instead of 201); the same key with a different body is a 409. The target's and observers'
/// current profile versions are recorded in the job. A display whose views diffraction leaves unresolved
/// does not stop the job; `warnings` says so.
#[utoipa::path(
    post, path = "/v1/jobs", tag = "jobs",
    request_body = CreateJob,
    params(("Idempotency-Key" = Option<String>, Header, description = "Makes retries of this request safe")),
    responses(
        (status = 201, description = "Queued", body = JobView),
        (status = 200, description = "Same key and body as an earlier request: that job", body = JobView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 409, description = "The key was used with a different body", body = ErrorBody),
        (status = 422, description = "A referenced resource does not exist, or bad options", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn create_job(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    headers: HeaderMap,
    ApiJson(body): ApiJson<CreateJob>,
) -> Result<Response, ApiError> {
    let idempotency_key = idempotency_key(&headers)?;
    let options = body.options.clone().unwrap_or_default();
    check_options(&options)?;
    if body.observer_profile_ids.len() > 16 {
        return Err(ApiError::invalid("observer_profile_ids", "at most 16 observers"));
    }
    let request_hash = request_hash(&state.master_key, &body, &options)?;
    let (display, target, observers, layout) = resolve_inputs(&state, &body).await?;
    // The job states the options it runs with: the display's defaults filled in (the decoys' weight), a seed
    // drawn for it from the operating system's CSPRNG unless one was given, and the layout of a document rendered
    // from text as its text hint unless one was given (the known-font attacker then judges it); sealed with the
    // job.
    let mut options = options.for_display(&display).with_fresh_seed();
    if options.document_text.is_none() {
        options.document_text = layout;
    }
    let warnings = resolvability_warnings(&Resolvability::of(&display));
    admit(&state.config, &display, &options, observers.len())?;
    if options.document_text.is_none() && options.ensure_target_reads {
        // Without a text hint only the legibility judge says whether the target reads: refuse a document it
        // cannot judge on this display before anything is queued.
        let document = crate::service::jobs::load_image(&state, &id_text(&body.document_id), "target")
            .await
            .map_err(|e| match e {
                crate::service::jobs::LoadError::Fatal(why) => ApiError::invalid("document_id", why),
                crate::service::jobs::LoadError::Transient(e) => ApiError::Internal(e),
            })?;
        eyekey_core::encoding::pipeline::check_judged_text_size(&document, &display).map_err(|e| match e {
            PipelineError::Invalid { field: _, reason } => ApiError::invalid("document_id", reason),
            other => ApiError::Internal(other.into()),
        })?;
    }
    let id = JobId::new_v4();
    let key = DataKey::generate();
    let internal = |e: crate::service::crypto::CryptoError| ApiError::Internal(e.into());
    let data_key = key
        .wrap(&state.master_key, &sealed::job_key_aad(&id.to_string()))
        .map_err(internal)?;
    let (clear_options, secret) = sealed::split_options(&options).map_err(|e| ApiError::Internal(e.into()))?;
    let sealed_options = secret
        .map(|s| key.seal(&s, &sealed::job_options_aad(&id.to_string())))
        .transpose()
        .map_err(internal)?;
    let new = NewJob {
        id,
        display_id: id_text(&body.display_id),
        document_id: id_text(&body.document_id),
        decoy_document_id: body.decoy_document_id.as_ref().map(id_text),
        profile_id: target.id,
        profile_version: target.current_version,
        observers: to_json(&observers)?,
        method: to_json(&options.method)?.trim_matches('"').to_string(),
        options: clear_options,
        max_attempts: state.config.queue.max_attempts.into(),
        idempotency_key,
        request_hash,
        data_key,
        sealed_options,
    };
    let (status, row) = enqueue(&state, &op.actor(), &new).await?;
    let mut response = (status, Json(JobView::new(&state.master_key, &row, warnings)?)).into_response();
    if let Ok(location) = HeaderValue::from_str(&format!("/v1/jobs/{}", row.id)) {
        response.headers_mut().insert(header::LOCATION, location);
    }
    Ok(response)
}

/// The keyed digest of the canonical request (options filled in), which identifies "the same request" for
/// idempotency. Keyed, because the request may carry the document's text.
fn request_hash(master: &MasterKey, body: &CreateJob, options: &EncodeOptions) -> Result<String, ApiError> {
    let canonical = CreateJob {
        options: Some(options.clone()),
        ..body.clone()
    };
    let bytes = serde_json::to_vec(&canonical).map_err(|e| ApiError::Internal(e.into()))?;
    Ok(master.digest("job-request", &bytes))
}

/// Refuses a job whose estimated peak memory or time exceeds the configured limits, naming the estimate,
/// the limits and what drives them, before anything is queued.
fn admit(
    config: &crate::service::Config,
    display: &DisplayGeometry,
    options: &EncodeOptions,
    observers: usize,
) -> Result<(), ApiError> {
    let f = footprint(display, options, observers);
    let (memory, seconds) = (config.max_job_memory_bytes, config.max_job_seconds);
    if f.peak_bytes <= memory && f.seconds <= seconds {
        return Ok(());
    }
    Err(ApiError::invalid(
        "options",
        format!(
            "this job would need an estimated {} MiB and {:.0} s ({} unknowns, {} observers rendered by the \
             solver), over the limits of {} MiB (--max-job-memory-mb) and {:.0} s (--max-job-seconds): use \
             fewer population_decoys, observers, head_positions or max_iterations, or a smaller display",
            f.peak_bytes >> 20,
            f.seconds,
            f.unknowns,
            f.observers,
            memory >> 20,
            seconds
        ),
    ))
}

/// What a job creation refers to: the display's geometry, the target profile, the observers pinned to their
/// current versions, and the layout of a document rendered from text.
type Inputs = (
    DisplayGeometry,
    store::profiles::ProfileRow,
    Vec<ObserverRef>,
    Option<eyekey_core::evaluation::DocumentText>,
);

/// Checks that every input of a job creation exists and returns them.
async fn resolve_inputs(state: &AppState, body: &CreateJob) -> Result<Inputs, ApiError> {
    let db = &state.db;
    let display = store::displays::get(db, &id_text(&body.display_id))
        .await?
        .ok_or_else(|| ApiError::invalid("display_id", "no such display"))?;
    let geometry = stored_geometry(&display.geometry)?;
    let document = store::documents::get(db, &id_text(&body.document_id))
        .await?
        .ok_or_else(|| ApiError::invalid("document_id", "no such document"))?;
    let layout = sealed::document_layout(&state.master_key, &document)
        .map_err(|e| ApiError::Internal(e.context("the document's layout")))?;
    if let Some(decoy) = &body.decoy_document_id {
        store::documents::get(db, &id_text(decoy))
            .await?
            .ok_or_else(|| ApiError::invalid("decoy_document_id", "no such document"))?;
    }
    let target = store::profiles::get(db, &id_text(&body.profile_id))
        .await?
        .ok_or_else(|| ApiError::invalid("profile_id", "no such profile"))?;
    let mut observers = Vec::with_capacity(body.observer_profile_ids.len());
    for (i, id) in body.observer_profile_ids.iter().enumerate() {
        let p = store::profiles::get(db, &id_text(id))
            .await?
            .ok_or_else(|| ApiError::invalid(format!("observer_profile_ids[{i}]"), "no such profile"))?;
        observers.push(ObserverRef {
            profile_id: p.id,
            version: p.current_version,
        });
    }
    Ok((geometry, target, observers, layout))
}

/// Enqueues a job, or finds the one this idempotency key already created: `201` and the new job (audited,
/// published and handed to a worker), `200` and the existing one, or a conflict when the key was used
/// for a different request.
async fn enqueue(state: &AppState, actor: &str, new: &NewJob) -> Result<(StatusCode, JobRow), ApiError> {
    match store::jobs::enqueue(&state.writer, new).await? {
        Enqueued::Created(row) => {
            store::audit::record(&state.writer, actor, "job.create", &format!("jobs/{}", row.id)).await?;
            state.publish(&row);
            state.job_queued.notify_one();
            Ok((StatusCode::CREATED, row))
        }
        Enqueued::Existing(row) => Ok((StatusCode::OK, row)),
        Enqueued::KeyReused(row) => Err(ApiError::Conflict {
            code: "idempotency_key_reused",
            message: format!(
                "this Idempotency-Key was used for job {} with a different request",
                row.id
            ),
        }),
    }
}

fn to_json<T: Serialize>(v: &T) -> Result<String, ApiError> {
    serde_json::to_string(v).map_err(|e| ApiError::Internal(e.into()))
}

async fn load(state: &AppState, id: &Uuid) -> Result<JobRow, ApiError> {
    store::jobs::get(&state.db, JobId::from(*id))
        .await?
        .ok_or(ApiError::NotFound("job"))
}

/// Read a job: state, progress, attempts, timings, last error and evaluation summary.
#[utoipa::path(
    get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = JobView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
    ),
    security(("operator" = ["submit", "read-evaluation", "admin"]))
)]
pub async fn get_job(
    State(state): State<AppState>,
    _op: Operator<scope::ReadJobs>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<JobView>, ApiError> {
    let row = load(&state, &id).await?;
    let warnings = display_warnings(&state, &row.display_id).await?;
    Ok(Json(JobView::new(&state.master_key, &row, warnings)?))
}

/// List jobs, newest first, optionally by state and display.
#[utoipa::path(
    get, path = "/v1/jobs", tag = "jobs",
    params(JobListQuery),
    responses(
        (status = 200, description = "A page of jobs", body = JobList),
        (status = 400, description = "Unknown state", body = ErrorBody),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("operator" = ["submit", "read-evaluation", "admin"]))
)]
pub async fn list_jobs(
    State(state): State<AppState>,
    _op: Operator<scope::ReadJobs>,
    ApiQuery(q): ApiQuery<JobListQuery>,
) -> Result<Json<JobList>, ApiError> {
    let (limit, cursor) = PageQuery {
        limit: q.limit,
        cursor: q.cursor,
    }
    .parse()?;
    let filter = JobFilter {
        state: q.state,
        display_id: q.display_id.as_ref().map(id_text),
    };
    let rows = store::jobs::list(&state.db, &filter, limit, cursor.as_ref()).await?;
    let mut items = Vec::with_capacity(rows.len());
    for row in &rows {
        items.push(JobView::new(
            &state.master_key,
            row,
            display_warnings(&state, &row.display_id).await?,
        )?);
    }
    Ok(Json(JobList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.to_string())),
        items,
    }))
}

/// Cancel a job (best effort).
///
/// A queued job is cancelled at once (200). A running job is asked to stop (202, `cancel_requested`);
/// its worker stops between solver iterations and the job ends `cancelled` (or `succeeded`, if it
/// finished first). Cancelling a cancelled job is a no-op; a succeeded or failed one is a 409.
#[utoipa::path(
    post, path = "/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled", body = JobView),
        (status = 202, description = "Running; asked to stop", body = JobView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "Already succeeded or failed", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn cancel_job(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<(StatusCode, Json<JobView>), ApiError> {
    let row = store::jobs::request_cancel(&state.writer, JobId::from(id))
        .await?
        .ok_or(ApiError::NotFound("job"))?;
    let status = match row.state {
        JobState::Cancelled => StatusCode::OK,
        JobState::Running => StatusCode::ACCEPTED,
        other => {
            return Err(ApiError::Conflict {
                code: "job_finished",
                message: format!("the job has already {}", other.as_str()),
            })
        }
    };
    store::audit::record(&state.writer, &op.actor(), "job.cancel", &format!("jobs/{}", row.id)).await?;
    state.publish(&row);
    let warnings = display_warnings(&state, &row.display_id).await?;
    Ok((status, Json(JobView::new(&state.master_key, &row, warnings)?)))
}

/// Delete a job and what it produced.
///
/// Its data key is destroyed and its evaluation, views and bundle removed; a queued job is cancelled, a
/// running one stopped (it ends `cancelled`, its output dropped). Its display can no longer fetch its frames.
/// The job stays as a tombstone in the audit log; reading it is a 404.
#[utoipa::path(
    delete, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn delete_job(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    let row = load(&state, &id).await?;
    let mut tx = state.writer.0.begin().await?;
    let purged = store::jobs::purge(&mut tx, store::jobs::JobSet::One(row.id), "deleted", store::now_ms()).await?;
    tx.commit().await?;
    if purged.jobs.is_empty() {
        return Err(ApiError::NotFound("job"));
    }
    store::audit::record(&state.writer, &op.actor(), "job.delete", &format!("jobs/{id}")).await?;
    // Wakes the job's event streams, which then find it gone and end.
    state.publish(&row);
    crate::service::retention::finish_deletion(&state, &purged.paths).await;
    Ok(StatusCode::NO_CONTENT)
}

/// Follow a job: server-sent events.
///
/// Sends the job (as in `GET /v1/jobs/{id}`) at once, then whenever it changes: event `state` when the
/// state changes, `progress` when only progress does. The stream ends after a terminal state.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "An event stream of JobView objects", content_type = "text/event-stream", body = JobView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
    ),
    security(("operator" = ["submit", "read-evaluation", "admin"]))
)]
pub async fn job_events(
    State(state): State<AppState>,
    _op: Operator<scope::ReadJobs>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let row = load(&state, &id).await?;
    // A display's geometry never changes, so neither do its warnings.
    let warnings = display_warnings(&state, &row.display_id).await?;
    let follow = Follow {
        id: row.id,
        warnings,
        rx: state.events.subscribe(),
        shutdown: state.shutdown.clone(),
        state,
        last: None,
        done: false,
    };
    let stream = futures::stream::unfold(follow, |mut f| async move {
        let event = f.next_event().await?;
        Some((Ok(event), f))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

/// The state of one job event stream.
struct Follow {
    state: AppState,
    id: JobId,
    /// The display's warnings, sent with every view.
    warnings: Vec<String>,
    rx: tokio::sync::broadcast::Receiver<JobEvent>,
    shutdown: tokio::sync::watch::Receiver<bool>,
    /// (state, progress in thousandths, attempts) last sent.
    last: Option<(JobState, i64, i64)>,
    done: bool,
}

impl Follow {
    /// The next event to send, or `None` to end the stream. The database is the source of truth; the
    /// broadcast only says when to look again (and a periodic look covers missed broadcasts).
    async fn next_event(&mut self) -> Option<Event> {
        if self.done {
            return None;
        }
        loop {
            let row = match store::jobs::get(&self.state.db, self.id).await {
                Ok(Some(row)) => row,
                Ok(None) => return None,
                Err(e) => {
                    tracing::warn!(error = %e, "job event stream: database read failed");
                    return None;
                }
            };
            let key = (row.state, (row.progress * 1000.0).round() as i64, row.attempts);
            if self.last.as_ref() != Some(&key) {
                let kind = if self.last.as_ref().map(|l| &l.0) == Some(&key.0) {
                    "progress"
                } else {
                    "state"
                };
                self.last = Some(key);
                self.done = row.state.is_terminal();
                let view = JobView::new(&self.state.master_key, &row, self.warnings.clone()).ok()?;
                return Some(Event::default().event(kind).data(serde_json::to_string(&view).ok()?));
            }
            if !self.wait().await {
                return None;
            }
        }
    }

    /// Waits for a change to this job, a second to pass, or shutdown (false).
    async fn wait(&mut self) -> bool {
        let tick = tokio::time::sleep(Duration::from_secs(1));
        tokio::pin!(tick);
        loop {
            tokio::select! {
                r = self.rx.recv() => match r {
                    Ok(ev) if ev.job_id == self.id => return true,
                    Ok(_) => continue,
                    Err(RecvError::Lagged(_)) => return true,
                    Err(RecvError::Closed) => return false,
                },
                _ = &mut tick => return true,
                _ = crate::service::state::stopped(&mut self.shutdown) => return false,
            }
        }
    }
}
