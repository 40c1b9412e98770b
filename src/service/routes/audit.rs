//! `/v1/audit`: the append-only audit log (operator only).

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use super::{next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiQuery, ErrorBody};
use crate::service::state::AppState;
use crate::service::store::{self, to_time};

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

/// `?resource=` of the audit log (beside the page's `?limit=&cursor=`).
#[derive(Debug, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ResourceFilter {
    /// Only entries about this resource and what lies under it: `jobs/<id>` gives the job's entries and its
    /// frame downloads (`jobs/<id>/…`).
    #[param(max_length = 200, pattern = r"^[a-z]+(/[0-9a-z._-]+)*$")]
    pub resource: Option<String>,
}

/// Read the audit log, newest first: who did what to which resource and when (never profile contents).
#[utoipa::path(
    get, path = "/v1/audit", tag = "audit",
    params(PageQuery, ResourceFilter),
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
    ApiQuery(filter): ApiQuery<ResourceFilter>,
) -> Result<Json<AuditList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    if let Some(resource) = &filter.resource {
        let segment_ok = |s: &str| {
            !s.is_empty()
                && s.bytes()
                    .all(|b| b.is_ascii_digit() || b.is_ascii_lowercase() || b"._-".contains(&b))
        };
        let mut parts = resource.split('/');
        let head_ok = parts
            .next()
            .is_some_and(|h| !h.is_empty() && h.bytes().all(|b| b.is_ascii_lowercase()));
        if resource.len() > 200 || !head_ok || !parts.all(segment_ok) {
            return Err(ApiError::invalid(
                "resource",
                "a resource is a kind and path segments, e.g. `jobs/<id>`",
            ));
        }
    }
    let rows = store::audit::list(&state.db, limit, cursor.as_ref(), filter.resource.as_deref()).await?;
    let next_cursor = next_cursor(&rows, limit, |r| (r.created_at, r.id.to_string()));
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
