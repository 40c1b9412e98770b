//! Evaluation of a succeeded job (operator only): the report and the simulated views of the target,
//! the observers and a sample of the population, and the record of how the frames were encoded.

use axum::extract::State;
use axum::response::Response;
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::send_sealed;
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiPath, ErrorBody};
use crate::service::jobs::bundle::is_plain_file_name;
use crate::service::sealed;
use crate::service::state::AppState;
use crate::service::store::ids::JobId;
use crate::service::store::{self, jobs::JobRow, jobs::JobState};

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/jobs/{id}/evaluation", get(get_evaluation))
        .route("/v1/jobs/{id}/encoding", get(get_encoding))
        .route("/v1/jobs/{id}/views", get(list_views))
        .route("/v1/jobs/{id}/views/{name}", get(get_view))
}

/// The simulated views of a job.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ViewList {
    /// File names, for `/v1/jobs/{id}/views/{name}`.
    pub names: Vec<String>,
}

/// The job, once it has succeeded (its outputs exist then).
async fn succeeded(state: &AppState, id: &Uuid) -> Result<JobRow, ApiError> {
    let job = store::jobs::get(&state.db, JobId::from(*id))
        .await?
        .ok_or(ApiError::NotFound("job"))?;
    match (job.state, &job.bundle_path) {
        (JobState::Succeeded, Some(_)) => Ok(job),
        (s, _) => Err(ApiError::Conflict {
            code: "job_not_succeeded",
            message: format!("the job is {}; its evaluation exists once it has succeeded", s.as_str()),
        }),
    }
}

/// The job's evaluation report (`report.json`): fidelity for the target, legibility for everybody else.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/evaluation", tag = "evaluation",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The report", content_type = "application/json", body = Object),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job has not succeeded", body = ErrorBody),
    ),
    security(("operator" = ["read-evaluation", "admin"]))
)]
pub async fn get_evaluation(
    State(state): State<AppState>,
    _op: Operator<scope::ReadEvaluation>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Response, ApiError> {
    send_json_output(&state, &id, "report.json", "evaluation report").await
}

/// One of a succeeded job's operator-only JSON outputs (`report.json`, `encoding.json`), opened.
async fn send_json_output(state: &AppState, id: &Uuid, name: &str, what: &'static str) -> Result<Response, ApiError> {
    let job = succeeded(state, id).await?;
    send_sealed(state, &job, name, "application/json", None, what).await
}

/// How the job's frames were encoded (`encoding.json`): the options as run, with the seed the encode drew its
/// decoys, noise and kernels from, the target's profile label and the solver's record. An operator's: a display
/// never receives it.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/encoding", tag = "evaluation",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The record", content_type = "application/json", body = Object),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job has not succeeded", body = ErrorBody),
    ),
    security(("operator" = ["read-evaluation", "admin"]))
)]
pub async fn get_encoding(
    State(state): State<AppState>,
    _op: Operator<scope::ReadEvaluation>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Response, ApiError> {
    send_json_output(
        &state,
        &id,
        eyekey_core::encoding::pipeline::ENCODING_FILE,
        "encoding record",
    )
    .await
}

/// Names of the job's simulated views (PNG).
#[utoipa::path(
    get, path = "/v1/jobs/{id}/views", tag = "evaluation",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "View names", body = ViewList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job has not succeeded", body = ErrorBody),
    ),
    security(("operator" = ["read-evaluation", "admin"]))
)]
pub async fn list_views(
    State(state): State<AppState>,
    _op: Operator<scope::ReadEvaluation>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<ViewList>, ApiError> {
    let job = succeeded(&state, &id).await?;
    let dir = format!("{}/views", job.bundle_path.as_deref().unwrap_or_default());
    let names: Vec<String> = state
        .objects
        .list(&dir)
        .await
        .map_err(ApiError::from_io)?
        .into_iter()
        .filter_map(|name| name.strip_suffix(sealed::SUFFIX).map(str::to_string))
        .filter(|name| name.ends_with(".png") && is_plain_file_name(name))
        .collect();
    Ok(Json(ViewList { names }))
}

/// One simulated view: what the target, an observer or a sampled person would see.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/views/{name}", tag = "evaluation",
    params(("id" = Uuid, Path, description = "Job id"), ("name" = String, Path, description = "View file name")),
    responses(
        (status = 200, description = "The view", content_type = "image/png", body = Vec<u8>),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such job or view", body = ErrorBody),
        (status = 409, description = "The job has not succeeded", body = ErrorBody),
    ),
    security(("operator" = ["read-evaluation", "admin"]))
)]
pub async fn get_view(
    State(state): State<AppState>,
    _op: Operator<scope::ReadEvaluation>,
    ApiPath((id, name)): ApiPath<(Uuid, String)>,
) -> Result<Response, ApiError> {
    if !is_plain_file_name(&name) || !name.ends_with(".png") {
        return Err(ApiError::NotFound("view"));
    }
    let job = succeeded(&state, &id).await?;
    send_sealed(&state, &job, &format!("views/{name}"), "image/png", None, "view").await
}
