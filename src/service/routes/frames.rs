//! `/v1/frames`: what a display client may fetch with its own token: the frame bundles of its own
//! succeeded jobs. Never profiles, evaluation reports or simulated views. Another display's job is a
//! 404, as if it did not exist.

use std::convert::Infallible;

use axum::extract::State;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::Response;
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use futures::Stream;
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast::error::RecvError;
use uuid::Uuid;

use super::{content_type_of, next_cursor, send_sealed, PageQuery};
use crate::service::auth::DisplayClient;
use crate::service::error::{ApiError, ApiPath, ApiQuery, ErrorBody};
use crate::service::jobs::bundle::{is_bundle_file, BundleFile, ZIP_NAME};
use crate::service::state::AppState;
use crate::service::store::ids::JobId;
use crate::service::store::jobs::{JobFilter, JobRow, JobState};
use crate::service::store::{self, to_time};

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/frames/jobs", get(list_frame_jobs))
        .route("/v1/frames/jobs/{id}", get(get_frame_job))
        .route("/v1/frames/jobs/{id}/bundle.zip", get(download_bundle))
        .route("/v1/frames/jobs/{id}/files/{name}", get(download_file))
        .route("/v1/frames/events", get(frame_events))
}

/// A succeeded job as its display sees it.
#[derive(Clone, Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FrameJob {
    /// Job id.
    pub id: Uuid,
    /// When the job was created.
    pub created_at: DateTime<Utc>,
    /// When its bundle was completed.
    pub finished_at: Option<DateTime<Utc>>,
    /// The bundle's files: `frame_<n>.png` (one 16-bit frame per projector), `barrier_mask.png`,
    /// `manifest.json`; fetch each at `files/{name}` or all at `bundle.zip`.
    pub files: Vec<BundleFile>,
}

/// A page of frame jobs.
#[derive(Clone, Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FrameJobList {
    /// Succeeded jobs, newest first.
    pub items: Vec<FrameJob>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

fn frame_job(row: &JobRow) -> FrameJob {
    FrameJob {
        id: row.id.as_uuid(),
        created_at: to_time(row.created_at),
        finished_at: row.finished_at.map(to_time),
        files: row
            .bundle_files
            .as_deref()
            .and_then(|s| serde_json::from_str(s).ok())
            .unwrap_or_default(),
    }
}

/// This display's succeeded job with a bundle, else 404 (also for other displays' jobs).
async fn own_job(state: &AppState, client: &DisplayClient, id: &Uuid) -> Result<JobRow, ApiError> {
    store::jobs::get(&state.db, JobId::from(*id))
        .await?
        .filter(|j| j.display_id == client.display_id && j.state == JobState::Succeeded && j.bundle_path.is_some())
        .ok_or(ApiError::NotFound("job"))
}

/// List this display's succeeded jobs, newest first.
#[utoipa::path(
    get, path = "/v1/frames/jobs", tag = "frames",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of this display's bundles", body = FrameJobList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("display" = []))
)]
pub async fn list_frame_jobs(
    State(state): State<AppState>,
    client: DisplayClient,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<FrameJobList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let filter = JobFilter {
        state: Some(JobState::Succeeded),
        display_id: Some(client.display_id.clone()),
    };
    let rows = store::jobs::list(&state.db, &filter, limit, cursor.as_ref()).await?;
    Ok(Json(FrameJobList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.to_string())),
        items: rows.iter().map(frame_job).collect(),
    }))
}

/// Read one of this display's bundles (its file list with checksums).
#[utoipa::path(
    get, path = "/v1/frames/jobs/{id}", tag = "frames",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The bundle's file list", body = FrameJob),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such bundle for this display", body = ErrorBody),
    ),
    security(("display" = []))
)]
pub async fn get_frame_job(
    State(state): State<AppState>,
    client: DisplayClient,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<FrameJob>, ApiError> {
    Ok(Json(frame_job(&own_job(&state, &client, &id).await?)))
}

/// Download a bundle as one zip (frames, barrier mask, manifest).
#[utoipa::path(
    get, path = "/v1/frames/jobs/{id}/bundle.zip", tag = "frames",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The bundle", content_type = "application/zip", body = Vec<u8>),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such bundle for this display", body = ErrorBody),
    ),
    security(("display" = []))
)]
pub async fn download_bundle(
    State(state): State<AppState>,
    client: DisplayClient,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Response, ApiError> {
    let job = own_job(&state, &client, &id).await?;
    let download = format!("eyekey-{}.zip", job.id);
    let response = send_sealed(&state, &job, ZIP_NAME, "application/zip", Some(&download), "bundle").await?;
    store::audit::record(
        &state.writer,
        &client.actor(),
        "frames.download",
        &format!("jobs/{}/{ZIP_NAME}", job.id),
    )
    .await?;
    Ok(response)
}

/// Download one bundle file: `frame_<n>.png`, `barrier_mask.png` or `manifest.json`.
#[utoipa::path(
    get, path = "/v1/frames/jobs/{id}/files/{name}", tag = "frames",
    params(("id" = Uuid, Path, description = "Job id"), ("name" = String, Path, description = "File name from the bundle's list")),
    responses(
        (status = 200, description = "The file", content((Vec<u8> = "image/png"), (Vec<u8> = "application/json"))),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such bundle or file for this display", body = ErrorBody),
    ),
    security(("display" = []))
)]
pub async fn download_file(
    State(state): State<AppState>,
    client: DisplayClient,
    ApiPath((id, name)): ApiPath<(Uuid, String)>,
) -> Result<Response, ApiError> {
    // Only bundle files: report.json and views/ may reveal profile-derived data.
    if !is_bundle_file(&name) {
        return Err(ApiError::NotFound("bundle file"));
    }
    let job = own_job(&state, &client, &id).await?;
    let response = send_sealed(&state, &job, &name, content_type_of(&name), None, "bundle file").await?;
    store::audit::record(
        &state.writer,
        &client.actor(),
        "frames.download",
        &format!("jobs/{}/files/{name}", job.id),
    )
    .await?;
    Ok(response)
}

/// Wait for new bundles: server-sent events.
///
/// Sends event `job_succeeded` with a `FrameJob` whenever one of this display's jobs succeeds. Events
/// missed while disconnected are not replayed: list `/v1/frames/jobs` after (re)connecting.
#[utoipa::path(
    get, path = "/v1/frames/events", tag = "frames",
    responses(
        (status = 200, description = "An event stream of FrameJob objects", content_type = "text/event-stream", body = FrameJob),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("display" = []))
)]
pub async fn frame_events(
    State(state): State<AppState>,
    client: DisplayClient,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let rx = state.events.subscribe();
    let shutdown = state.shutdown.clone();
    let stream = futures::stream::unfold(
        (state, client.display_id, rx, shutdown),
        |(state, me, mut rx, mut shutdown)| async move {
            loop {
                tokio::select! {
                    r = rx.recv() => match r {
                        Ok(ev) if ev.display_id == me && ev.state == JobState::Succeeded => {
                            let Ok(Some(row)) = store::jobs::get(&state.db, ev.job_id).await else { continue };
                            let Ok(data) = serde_json::to_string(&frame_job(&row)) else { continue };
                            let event = Event::default().event("job_succeeded").data(data);
                            return Some((Ok(event), (state, me, rx, shutdown)));
                        }
                        Ok(_) | Err(RecvError::Lagged(_)) => continue,
                        Err(RecvError::Closed) => return None,
                    },
                    _ = crate::service::state::stopped(&mut shutdown) => return None,
                }
            }
        },
    );
    Sse::new(stream).keep_alive(KeepAlive::default())
}
