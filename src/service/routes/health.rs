//! Liveness and readiness probes (no authentication).

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};

use crate::service::error::{ApiError, ErrorBody};
use crate::service::state::AppState;
use crate::service::store;

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
}

/// A probe's answer.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Health {
    /// `ok` or `ready`.
    pub status: String,
}

/// Liveness: the process serves HTTP.
#[utoipa::path(get, path = "/healthz", tag = "operations", responses((status = 200, description = "Alive", body = Health)))]
pub async fn healthz() -> Json<Health> {
    Json(Health { status: "ok".into() })
}

/// Readiness: the database answers, every migration is applied, and the service is not shutting down.
#[utoipa::path(
    get, path = "/readyz", tag = "operations",
    responses(
        (status = 200, description = "Ready", body = Health),
        (status = 503, description = "Not ready, and why", body = ErrorBody),
    )
)]
pub async fn readyz(State(state): State<AppState>) -> Result<Json<Health>, ApiError> {
    if state.shutting_down() {
        return Err(ApiError::Unavailable("shutting down".into()));
    }
    storage_ready(&state).await?;
    match store::migrations_applied(&state.db).await {
        Ok(true) => Ok(Json(Health { status: "ready".into() })),
        Ok(false) => Err(ApiError::Unavailable("database migrations are not all applied".into())),
        Err(e) => {
            tracing::warn!(error = %e, "readiness: database unreachable");
            Err(ApiError::Unavailable("the database does not answer".into()))
        }
    }
}

/// The data directory must take a write and have at least `min_free_bytes` free: a service that cannot store
/// an upload or a bundle is not ready.
async fn storage_ready(state: &AppState) -> Result<(), ApiError> {
    let dir = state.data_dir().clone();
    let min_free = state.config.min_free_bytes;
    let probe = dir.join(".readyz-probe");
    let written = tokio::fs::write(&probe, b"ok").await;
    let _ = tokio::fs::remove_file(&probe).await;
    if let Err(e) = written {
        tracing::warn!(error = %e, dir = %dir.display(), "readiness: the data directory does not take a write");
        return Err(ApiError::Unavailable(format!(
            "the data directory is not writable: {e}"
        )));
    }
    match free_bytes(&dir) {
        Some(free) if free < min_free => Err(ApiError::Unavailable(format!(
            "the data directory is nearly full: {} MiB free, at least {} MiB needed (--min-free-mb)",
            free >> 20,
            min_free >> 20
        ))),
        _ => Ok(()),
    }
}

/// Bytes available to this process on the file system holding `dir` (`statvfs`), where it can be read.
pub fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt as _;
        let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
        let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
        // SAFETY: `path` is a NUL-terminated string and `stat` a valid, writable statvfs.
        if unsafe { libc::statvfs(path.as_ptr(), &mut stat) } != 0 {
            return None;
        }
        Some(stat.f_bavail as u64 * stat.f_frsize as u64)
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        None
    }
}
