//! `/v1/displays`: registered light-field displays (operator only). Each gets an access token, shown
//! once and stored as its SHA-256.

use axum::extract::State;
use axum::http::StatusCode;
use axum::routing::{get, post};
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::{id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::crypto::{generate_token, token_hash};
use crate::service::error::{ApiError, ApiJson, ApiPath, ApiQuery, ErrorBody};
use crate::service::state::AppState;
use crate::service::store::{self, displays::DisplayRow, to_time};
use eyekey_core::physics::display::{DisplayError, DisplayGeometry};
use eyekey_core::physics::resolvability::Resolvability;

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/displays", get(list_displays).post(register_display))
        .route("/v1/displays/{id}", get(get_display).delete(delete_display))
        .route("/v1/displays/{id}/token", post(rotate_token))
}

/// A built-in display design.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// The paper's setup: 100×100 holes, 5×5 views, 4 projectors.
    Paper,
    /// 32×32 lenslets of 1 mm, 9×9 views 0.6 mm apart: the display eyekey's secrecy is measured on, and its
    /// default options were chosen for.
    Secure,
    /// 24×24 holes, 5×5 views: for tests and demos.
    Small,
    /// 48×48 lenslets of 1 mm, 9×9 views: resolves its views under diffraction.
    Lenslet,
    /// 48×48 holes of 0.15 mm, 5×5 views 2.5 mm apart: resolves its views under diffraction.
    Pinhole,
    /// 48×48 holes of 33 µm, 9×9 views: angular freedom under geometric optics only (diffraction does not
    /// resolve its views).
    Dense,
}

/// Body of a registration: a name and either a preset or a full geometry. Its schema is
/// [`RegisterDisplaySchema`], which states the "exactly one of" rule.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterDisplay {
    /// Operator's name for the display.
    pub name: String,
    /// A built-in design (give this or `geometry`).
    pub preset: Option<Preset>,
    /// Full geometry, projector spectra and viewing distance (give this or `preset`).
    pub geometry: Option<DisplayGeometry>,
}

/// Body of a registration: a name and exactly one of `preset` and `geometry`.
#[derive(Deserialize, utoipa::ToSchema)]
#[schema(as = RegisterDisplay)]
#[allow(dead_code)] // a schema only: requests are read as [`RegisterDisplay`]
#[serde(untagged)]
pub enum RegisterDisplaySchema {
    /// A built-in design.
    Preset(RegisterByPreset),
    /// A full geometry.
    Geometry(RegisterByGeometry),
}

/// Registration from a built-in design.
#[derive(Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)] // a schema only
pub struct RegisterByPreset {
    /// Operator's name for the display (1–200 characters, not blank, no control or bidirectional-override
    /// characters).
    #[schema(
        min_length = 1,
        max_length = 200,
        pattern = r"^[^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*[^\s\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB][^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*$"
    )]
    pub name: String,
    /// The design.
    pub preset: Preset,
}

/// Registration from a full geometry.
#[derive(Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)] // a schema only
pub struct RegisterByGeometry {
    /// Operator's name for the display (1–200 characters, not blank, no control or bidirectional-override
    /// characters).
    #[schema(
        min_length = 1,
        max_length = 200,
        pattern = r"^[^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*[^\s\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB][^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*$"
    )]
    pub name: String,
    /// Geometry, projector spectra and viewing distance.
    pub geometry: DisplayGeometry,
}

/// A registered display.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DisplayView {
    /// Id.
    pub id: Uuid,
    /// Name.
    pub name: String,
    /// Geometry, spectra and viewing distance.
    pub geometry: DisplayGeometry,
    /// Width of each projector frame, pixels (X·U).
    pub frame_width: u32,
    /// Height of each projector frame, pixels (Y·V).
    pub frame_height: u32,
    /// Number of projectors (frames per bundle).
    pub bands: usize,
    /// Whether diffraction at the apertures lets the views be told apart at the pupil, per band: view
    /// spacing s = p_s·d/g, the diffraction spread of one view, the resolvability M = A·s/(λ·d) (resolved
    /// while M ≥ 1) and the view channels a 4 mm and a 6 mm pupil separate. Computed from the geometry.
    pub resolvability: Resolvability,
    /// Problems with the design that do not stop it being registered or used: empty when every band
    /// resolves its views (M ≥ 1), else one line naming the worst band.
    pub warnings: Vec<String>,
    /// Registration time.
    pub created_at: DateTime<Utc>,
    /// When the current token was issued.
    pub token_issued_at: DateTime<Utc>,
}

/// A display with its access token. The token is shown only here, once.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DisplayWithToken {
    /// The display.
    pub display: DisplayView,
    /// Bearer token for `/v1/frames`; store it now, it cannot be shown again.
    pub token: String,
}

/// A page of displays.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DisplayList {
    /// Displays, newest first.
    pub items: Vec<DisplayView>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

/// The warnings a display's resolvability gives: empty when every band resolves its views.
pub(crate) fn resolvability_warnings(resolvability: &Resolvability) -> Vec<String> {
    resolvability.warning().into_iter().collect()
}

/// A stored geometry (`DisplayGeometry` JSON), parsed.
pub(crate) fn stored_geometry(json: &str) -> Result<DisplayGeometry, ApiError> {
    serde_json::from_str(json).map_err(|e| ApiError::Internal(anyhow::anyhow!("stored geometry: {e}")))
}

fn view(row: &DisplayRow) -> Result<DisplayView, ApiError> {
    let geometry = stored_geometry(&row.geometry)?;
    let (frame_width, frame_height) = geometry.frame_size();
    let resolvability = Resolvability::of(&geometry);
    Ok(DisplayView {
        id: row.id.parse().unwrap_or_default(),
        name: row.name.clone(),
        bands: geometry.n_bands(),
        warnings: resolvability_warnings(&resolvability),
        resolvability,
        geometry,
        frame_width,
        frame_height,
        created_at: to_time(row.created_at),
        token_issued_at: to_time(row.token_rotated_at),
    })
}

fn geometry_error(e: DisplayError) -> ApiError {
    let field = match &e {
        DisplayError::OutOfRange { field, .. } | DisplayError::Inconsistent { field, .. } => {
            format!("geometry.{field}")
        }
        DisplayError::Projector { index, .. } => format!("geometry.projectors[{index}]"),
        _ => "geometry".to_string(),
    };
    ApiError::invalid(field, e.to_string())
}

/// Display tokens start with this, so a leaked one is recognisable.
const TOKEN_PREFIX: &str = "ekd_";

/// Register a display.
///
/// Returns the display and its access token; the token is shown only in this response and stored
/// as its SHA-256. A design whose views diffraction leaves unresolved is still registered, with a line in
/// `warnings`.
#[utoipa::path(
    post, path = "/v1/displays", tag = "displays",
    request_body = RegisterDisplaySchema,
    responses(
        (status = 201, description = "Registered; the token is shown once", body = DisplayWithToken),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 422, description = "Invalid geometry, or one no job could run on within the memory limit; `field` names the problem", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn register_display(
    State(state): State<AppState>,
    op: Operator<scope::Admin>,
    ApiJson(body): ApiJson<RegisterDisplay>,
) -> Result<(StatusCode, Json<DisplayWithToken>), ApiError> {
    let name = super::check_name("name", &body.name, 200)?;
    let geometry = match (body.preset, body.geometry) {
        (Some(_), Some(_)) => return Err(ApiError::invalid("preset", "give either preset or geometry, not both")),
        (None, None) => return Err(ApiError::invalid("geometry", "give a preset or a geometry")),
        (Some(p), None) => {
            let name = serde_json::to_value(p)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default();
            DisplayGeometry::preset(&name).map_err(geometry_error)?
        }
        (None, Some(g)) => g,
    };
    geometry.validate().map_err(geometry_error)?;
    let cheapest = eyekey_core::encoding::footprint::cheapest(&geometry);
    let (memory, seconds) = (state.config.max_job_memory_bytes, state.config.max_job_seconds);
    if cheapest.peak_bytes > memory || cheapest.seconds > seconds {
        return Err(ApiError::invalid(
            "geometry",
            format!(
                "no job could run on this display: even the cheapest (the target alone, one iteration) needs an \
                 estimated {} MiB and {:.0} s for its {} unknowns, over the limits of {} MiB \
                 (--max-job-memory-mb) and {:.0} s (--max-job-seconds)",
                cheapest.peak_bytes >> 20,
                cheapest.seconds,
                cheapest.unknowns,
                memory >> 20,
                seconds
            ),
        ));
    }
    let geometry_json = serde_json::to_string(&geometry).map_err(|e| ApiError::Internal(e.into()))?;
    let id = id_text(&Uuid::new_v4());
    let token = generate_token(TOKEN_PREFIX);
    let row = store::displays::insert(&state.writer, &id, name, &geometry_json, &token_hash(&token)).await?;
    store::audit::record(
        &state.writer,
        &op.actor(),
        "display.register",
        &format!("displays/{id}"),
    )
    .await?;
    Ok((
        StatusCode::CREATED,
        Json(DisplayWithToken {
            display: view(&row)?,
            token,
        }),
    ))
}

/// Read a display (never its token).
#[utoipa::path(
    get, path = "/v1/displays/{id}", tag = "displays",
    params(("id" = Uuid, Path, description = "Display id")),
    responses(
        (status = 200, description = "The display", body = DisplayView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such display", body = ErrorBody),
    ),
    security(("operator" = ["submit", "read-evaluation", "admin"]))
)]
pub async fn get_display(
    State(state): State<AppState>,
    _op: Operator<scope::ReadJobs>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<DisplayView>, ApiError> {
    let row = store::displays::get(&state.db, &id_text(&id))
        .await?
        .ok_or(ApiError::NotFound("display"))?;
    Ok(Json(view(&row)?))
}

/// List displays, newest first.
#[utoipa::path(
    get, path = "/v1/displays", tag = "displays",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of displays", body = DisplayList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("operator" = ["submit", "read-evaluation", "admin"]))
)]
pub async fn list_displays(
    State(state): State<AppState>,
    _op: Operator<scope::ReadJobs>,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<DisplayList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let rows = store::displays::list(&state.db, limit, cursor.as_ref()).await?;
    Ok(Json(DisplayList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.clone())),
        items: rows.iter().map(view).collect::<Result<_, _>>()?,
    }))
}

/// Issue a new access token; the old one stops working at once.
#[utoipa::path(
    post, path = "/v1/displays/{id}/token", tag = "displays",
    params(("id" = Uuid, Path, description = "Display id")),
    responses(
        (status = 200, description = "The new token, shown once", body = DisplayWithToken),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such display", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn rotate_token(
    State(state): State<AppState>,
    op: Operator<scope::Admin>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<DisplayWithToken>, ApiError> {
    let id = id_text(&id);
    let token = generate_token(TOKEN_PREFIX);
    let row = store::displays::rotate_token(&state.writer, &id, &token_hash(&token))
        .await?
        .ok_or(ApiError::NotFound("display"))?;
    store::audit::record(
        &state.writer,
        &op.actor(),
        "display.rotate_token",
        &format!("displays/{id}"),
    )
    .await?;
    Ok(Json(DisplayWithToken {
        display: view(&row)?,
        token,
    }))
}

/// Delete a display: its token stops working, its queued jobs are cancelled and running ones stopped.
#[utoipa::path(
    delete, path = "/v1/displays/{id}", tag = "displays",
    params(("id" = Uuid, Path, description = "Display id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such display", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn delete_display(
    State(state): State<AppState>,
    op: Operator<scope::Admin>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    let id = id_text(&id);
    if !store::displays::delete(&state.writer, &id).await? {
        return Err(ApiError::NotFound("display"));
    }
    store::audit::record(&state.writer, &op.actor(), "display.delete", &format!("displays/{id}")).await?;
    Ok(StatusCode::NO_CONTENT)
}
