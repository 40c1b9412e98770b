//! `/v1/profiles`: enrolled vision profiles (operator only). Stored sealed; re-enrolment adds a version.

use axum::extract::State;
use axum::http::StatusCode;
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::{id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiJson, ApiPath, ApiQuery, ErrorBody};
use crate::service::state::AppState;
use crate::service::store::{self, profiles::ProfileRow, to_time};
use eyekey_core::physics::profile::{ProfileError, VisionProfile};

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/profiles", get(list_profiles).post(enrol_profile))
        .route(
            "/v1/profiles/{id}",
            get(get_profile).put(reenrol_profile).delete(delete_profile),
        )
}

/// Body of an enrolment or re-enrolment.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct EnrolProfile {
    /// Operator's label (not secret; at most 200 characters, no control or bidirectional-override characters).
    /// On re-enrolment, omitted keeps the old one.
    #[schema(
        max_length = 200,
        pattern = r"^[^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*$"
    )]
    pub label: Option<String>,
    /// The person's vision profile.
    pub profile: VisionProfile,
}

/// A profile's metadata (never its contents).
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProfileMeta {
    /// Id.
    pub id: Uuid,
    /// Operator's label.
    #[schema(max_length = 200)]
    pub label: Option<String>,
    /// Current version (1 on enrolment, +1 per re-enrolment).
    pub version: i64,
    /// First enrolment.
    pub created_at: DateTime<Utc>,
    /// Latest enrolment.
    pub updated_at: DateTime<Utc>,
}

/// A profile with its decrypted contents (operator only).
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProfileDetail {
    /// Id.
    pub id: Uuid,
    /// Operator's label.
    #[schema(max_length = 200)]
    pub label: Option<String>,
    /// The version shown.
    pub version: i64,
    /// Current version.
    pub current_version: i64,
    /// First enrolment.
    pub created_at: DateTime<Utc>,
    /// Latest enrolment.
    pub updated_at: DateTime<Utc>,
    /// The vision profile of `version`.
    pub profile: VisionProfile,
}

/// A page of profiles.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProfileList {
    /// Profiles, newest first.
    pub items: Vec<ProfileMeta>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

/// `?version=` of a profile read.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct VersionQuery {
    /// Version to read (default: the current one).
    pub version: Option<i64>,
}

impl From<&ProfileRow> for ProfileMeta {
    fn from(r: &ProfileRow) -> Self {
        Self {
            id: r.id.parse().unwrap_or_default(),
            label: r.label.clone(),
            version: r.current_version,
            created_at: to_time(r.created_at),
            updated_at: to_time(r.updated_at),
        }
    }
}

fn check(body: &EnrolProfile) -> Result<Vec<u8>, ApiError> {
    if let Some(label) = &body.label {
        super::check_text("label", label, 200)?;
    }
    body.profile.validate().map_err(|e| match e {
        ProfileError::Invalid { field, reason } => ApiError::invalid(format!("profile.{field}"), reason),
        other => ApiError::Invalid {
            field: Some("profile".into()),
            message: other.to_string(),
        },
    })?;
    serde_json::to_vec(&body.profile).map_err(|e| ApiError::Internal(e.into()))
}

fn detail(row: &ProfileRow, version: i64, profile: VisionProfile) -> ProfileDetail {
    ProfileDetail {
        id: row.id.parse().unwrap_or_default(),
        label: row.label.clone(),
        version,
        current_version: row.current_version,
        created_at: to_time(row.created_at),
        updated_at: to_time(row.updated_at),
        profile,
    }
}

/// Enrol a person's vision profile.
///
/// The profile is sealed with ChaCha20-Poly1305 under the master key before it is stored; the database
/// never holds it in the clear. Returns version 1.
#[utoipa::path(
    post, path = "/v1/profiles", tag = "profiles",
    request_body = EnrolProfile,
    responses(
        (status = 201, description = "Enrolled", body = ProfileDetail),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 422, description = "Invalid profile; `field` names the problem", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "admin"]))
)]
pub async fn enrol_profile(
    State(state): State<AppState>,
    op: Operator<scope::Enrol>,
    ApiJson(body): ApiJson<EnrolProfile>,
) -> Result<(StatusCode, Json<ProfileDetail>), ApiError> {
    let plain = check(&body)?;
    let id = id_text(&Uuid::new_v4());
    let row = store::profiles::insert(&state.writer, &state.master_key, &id, body.label.as_deref(), &plain).await?;
    store::audit::record(&state.writer, &op.actor(), "profile.enrol", &format!("profiles/{id}")).await?;
    Ok((StatusCode::CREATED, Json(detail(&row, 1, body.profile))))
}

/// Read a profile, decrypted (operator only; display clients never see profiles).
#[utoipa::path(
    get, path = "/v1/profiles/{id}", tag = "profiles",
    params(("id" = Uuid, Path, description = "Profile id"), VersionQuery),
    responses(
        (status = 200, description = "The profile", body = ProfileDetail),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such profile or version", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "admin"]))
)]
pub async fn get_profile(
    State(state): State<AppState>,
    _op: Operator<scope::Enrol>,
    ApiPath(id): ApiPath<Uuid>,
    ApiQuery(q): ApiQuery<VersionQuery>,
) -> Result<Json<ProfileDetail>, ApiError> {
    let id = id_text(&id);
    let row = store::profiles::get(&state.db, &id)
        .await?
        .ok_or(ApiError::NotFound("profile"))?;
    let version = q.version.unwrap_or(row.current_version);
    let sealed = store::profiles::get_version(&state.db, &id, version)
        .await?
        .ok_or(ApiError::NotFound("profile version"))?;
    let plain = sealed.open(&state.master_key)?;
    let profile: VisionProfile = serde_json::from_slice(&plain).map_err(|e| ApiError::Internal(e.into()))?;
    Ok(Json(detail(&row, version, profile)))
}

/// List profiles (metadata only), newest first.
#[utoipa::path(
    get, path = "/v1/profiles", tag = "profiles",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of profiles", body = ProfileList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 422, description = "Bad limit or cursor", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "admin"]))
)]
pub async fn list_profiles(
    State(state): State<AppState>,
    _op: Operator<scope::Enrol>,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<ProfileList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let rows = store::profiles::list(&state.db, limit, cursor.as_ref()).await?;
    Ok(Json(ProfileList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.clone())),
        items: rows.iter().map(ProfileMeta::from).collect(),
    }))
}

/// Re-enrol a person: stores a new version and makes it current.
///
/// Jobs already created keep the version they were created with.
#[utoipa::path(
    put, path = "/v1/profiles/{id}", tag = "profiles",
    params(("id" = Uuid, Path, description = "Profile id")),
    request_body = EnrolProfile,
    responses(
        (status = 200, description = "The new version", body = ProfileDetail),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such profile", body = ErrorBody),
        (status = 422, description = "Invalid profile", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "admin"]))
)]
pub async fn reenrol_profile(
    State(state): State<AppState>,
    op: Operator<scope::Enrol>,
    ApiPath(id): ApiPath<Uuid>,
    ApiJson(body): ApiJson<EnrolProfile>,
) -> Result<Json<ProfileDetail>, ApiError> {
    let plain = check(&body)?;
    let id = id_text(&id);
    let row = store::profiles::add_version(&state.writer, &state.master_key, &id, body.label.as_deref(), &plain)
        .await?
        .ok_or(ApiError::NotFound("profile"))?;
    store::audit::record(
        &state.writer,
        &op.actor(),
        "profile.reenrol",
        &format!("profiles/{id}/versions/{}", row.current_version),
    )
    .await?;
    Ok(Json(detail(&row, row.current_version, body.profile)))
}

/// Delete a profile.
///
/// Every sealed version is erased (the database overwrites freed pages and its log is checkpointed); a
/// tombstone keeps the id for the audit log. Everything derived from the profile goes too: every job it
/// was the target or an observer of is deleted with its evaluation and bundle (queued ones cancelled,
/// running ones stopped).
#[utoipa::path(
    delete, path = "/v1/profiles/{id}", tag = "profiles",
    params(("id" = Uuid, Path, description = "Profile id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such profile", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "admin"]))
)]
pub async fn delete_profile(
    State(state): State<AppState>,
    op: Operator<scope::Enrol>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    let id = id_text(&id);
    let purged = store::profiles::delete(&state.writer, &id)
        .await?
        .ok_or(ApiError::NotFound("profile"))?;
    store::audit::record(&state.writer, &op.actor(), "profile.delete", &format!("profiles/{id}")).await?;
    for job in &purged.jobs {
        store::audit::record(&state.writer, &op.actor(), "job.delete", &format!("jobs/{job}")).await?;
    }
    crate::service::retention::finish_deletion(&state, &purged.paths).await;
    Ok(StatusCode::NO_CONTENT)
}
