//! `/v1/audit`: the append-only audit log (operator only).

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use super::PageQuery;
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiQuery, ErrorBody};
use crate::service::state::AppState;
use crate::service::store::{self, to_time, Cursor};

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new().route("/v1/audit", get(list_audit))
}

/// One audit entry.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AuditEntry {
    /// Sequence number.
    pub id: i64,
    /// `operator` or `display:<id>`.
    pub actor: String,
    /// What was done, e.g. `profile.enrol`, `frames.download`.
    pub action: String,
    /// To what, e.g. `profiles/<id>`.
    pub resource: String,
    /// When.
    pub at: DateTime<Utc>,
}

/// A page of audit entries.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AuditList {
    /// Entries, newest first.
    pub items: Vec<AuditEntry>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

/// Read the audit log, newest first: who did what to which resource and when (never profile contents).
#[utoipa::path(
    get, path = "/v1/audit", tag = "audit",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of entries", body = AuditList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn list_audit(
    State(state): State<AppState>,
    _op: Operator<scope::Admin>,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<AuditList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let rows = store::audit::list(&state.db, limit, cursor.as_ref()).await?;
    let next_cursor = (rows.len() == limit as usize)
        .then(|| {
            rows.last().map(|r| {
                Cursor {
                    created_at: r.created_at,
                    id: r.id.to_string(),
                }
                .encode()
            })
        })
        .flatten();
    Ok(Json(AuditList {
        items: rows
            .into_iter()
            .map(|r| AuditEntry {
                id: r.id,
                actor: r.actor,
                action: r.action,
                resource: r.resource,
                at: to_time(r.created_at),
            })
            .collect(),
        next_cursor,
    }))
}
