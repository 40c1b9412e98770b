//! `DIR/state.json`: which job `current/` and `previous/` show.

use std::io::Write as _;
use std::path::Path;

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::error::{io_err, ClientError};
use super::STATE_FILE;

/// `DIR/state.json`: what the client shows. Never holds the token.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClientState {
    /// The job in `current/`.
    pub current: Option<ShownJob>,
    /// The job in `previous/`.
    pub previous: Option<ShownJob>,
}

/// One installed job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShownJob {
    /// Job id.
    pub job_id: Uuid,
    /// When the job was created.
    pub created_at: DateTime<Utc>,
    /// When the server completed its bundle.
    pub finished_at: Option<DateTime<Utc>>,
    /// When this client installed it.
    pub installed_at: DateTime<Utc>,
    /// SHA-256 of its `manifest.json`.
    pub manifest_sha256: String,
}

/// Reads `DIR/state.json`; a missing or unreadable one means nothing is shown (the newest job is then
/// installed again, which is harmless).
pub fn read_state(out_dir: &Path) -> ClientState {
    let path = out_dir.join(STATE_FILE);
    match std::fs::read(&path) {
        Ok(bytes) => serde_json::from_slice(&bytes).unwrap_or_else(|e| {
            tracing::warn!(path = %path.display(), error = %e, "ignoring an unreadable state file");
            ClientState::default()
        }),
        Err(_) => ClientState::default(),
    }
}

/// Writes `DIR/state.json` atomically (temporary file, fsync, rename).
pub(super) fn write_state(out_dir: &Path, state: &ClientState) -> Result<(), ClientError> {
    let path = out_dir.join(STATE_FILE);
    let mut json = serde_json::to_vec_pretty(state).map_err(|e| ClientError::Io {
        op: "serialise",
        path: path.clone(),
        source: std::io::Error::other(e),
    })?;
    json.push(b'\n');
    let mut tmp = tempfile::Builder::new()
        .prefix(".state-")
        .tempfile_in(out_dir)
        .map_err(io_err("create a temporary file in", out_dir))?;
    tmp.write_all(&json).map_err(io_err("write", tmp.path()))?;
    tmp.as_file().sync_all().map_err(io_err("sync", &path))?;
    tmp.persist(&path).map_err(|e| ClientError::Io {
        op: "replace",
        path: path.clone(),
        source: e.error,
    })?;
    Ok(())
}
