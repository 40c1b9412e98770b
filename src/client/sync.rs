//! One catch-up: install the display's newest job unless it is already shown.

use std::path::PathBuf;

use chrono::Utc;
use uuid::Uuid;

use super::config::ClientConfig;
use super::error::{io_err, ClientError};
use super::http::{download_bundle, newest_job};
use super::install::install_bundle;
use super::state::{read_state, write_state, ClientState, ShownJob};
use super::CURRENT_DIR;
use eyekey_core::bundle::MANIFEST_FILE;

/// What one sync did.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SyncOutcome {
    /// The server has no succeeded job for this display yet.
    NoJobs,
    /// The newest job is already in `current/`.
    UpToDate {
        /// The job shown.
        job_id: Uuid,
    },
    /// A new bundle was verified and now is `current/`.
    Installed {
        /// The job now shown.
        job_id: Uuid,
        /// Number of projector frames.
        frames: u32,
        /// `current/preview.png`, when a preview profile was given.
        preview: Option<PathBuf>,
    },
}

impl std::fmt::Display for SyncOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NoJobs => write!(f, "no new job: the server has no finished job for this display yet"),
            Self::UpToDate { job_id } => write!(f, "no new job: {CURRENT_DIR}/ already shows job {job_id}"),
            Self::Installed {
                job_id,
                frames,
                preview,
            } => {
                write!(
                    f,
                    "installed job {job_id}: {frames} frames and the barrier mask verified"
                )?;
                if let Some(p) = preview {
                    write!(f, ", preview in {}", p.display())?;
                }
                Ok(())
            }
        }
    }
}

/// One catch-up: installs the display's newest succeeded job into `current/` unless it is already there.
///
/// Downloads the bundle zip into a temporary file in the output directory, verifies it
/// ([`eyekey_core::bundle::read_verified_bundle`]: sizes, checksums, geometry) and checks it against the server's
/// listing, writes the preview if configured, and swaps the result into `current/`; updates `state.json` last.
pub async fn sync_once(cfg: &ClientConfig) -> Result<SyncOutcome, ClientError> {
    std::fs::create_dir_all(&cfg.out_dir).map_err(io_err("create", &cfg.out_dir))?;
    let Some(job) = newest_job(cfg).await? else {
        return Ok(SyncOutcome::NoJobs);
    };
    let state = read_state(&cfg.out_dir);
    let shown = state.current.as_ref().is_some_and(|c| c.job_id == job.id);
    if shown && cfg.current_dir().join(MANIFEST_FILE).is_file() {
        return Ok(SyncOutcome::UpToDate { job_id: job.id });
    }

    let zip = download_bundle(cfg, &job).await?;
    let out_dir = cfg.out_dir.clone();
    let preview = cfg.preview.clone();
    let job_for_install = job.clone();
    let installed = tokio::task::spawn_blocking(move || {
        let result = install_bundle(zip.path(), &out_dir, &job_for_install, preview.as_ref());
        drop(zip); // removes the downloaded zip
        result
    })
    .await
    .map_err(|e| ClientError::Io {
        op: "install the bundle into",
        path: cfg.current_dir(),
        source: std::io::Error::other(e),
    })??;

    let new_state = ClientState {
        current: Some(ShownJob {
            job_id: job.id,
            created_at: job.created_at,
            finished_at: job.finished_at,
            installed_at: Utc::now(),
            manifest_sha256: installed.manifest_sha256,
        }),
        previous: state.current,
    };
    write_state(&cfg.out_dir, &new_state)?;
    Ok(SyncOutcome::Installed {
        job_id: job.id,
        frames: installed.frames,
        preview: installed.preview,
    })
}
