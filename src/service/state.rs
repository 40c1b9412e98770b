//! What every handler and worker shares.

use std::path::PathBuf;
use std::sync::Arc;

use sqlx::AnyPool;
use tokio::sync::{broadcast, watch, Notify};

use super::config::Config;
use super::crypto::MasterKey;
use super::store::ids::JobId;
use super::store::jobs::{JobRow, JobState};
use super::store::Writer;

/// A change of a job's state or progress, broadcast to event streams.
#[derive(Clone, Debug)]
pub struct JobEvent {
    /// The job.
    pub job_id: JobId,
    /// Its display.
    pub display_id: String,
    /// Its state after the change.
    pub state: JobState,
    /// Its progress after the change.
    pub progress: f64,
}

impl JobEvent {
    /// The event describing a row.
    pub fn of(row: &JobRow) -> Self {
        Self {
            job_id: row.id,
            display_id: row.display_id.clone(),
            state: row.state,
            progress: row.progress,
        }
    }
}

/// Shared state, cheap to clone.
#[derive(Clone)]
pub struct AppState(pub Arc<Inner>);

/// The contents of [`AppState`].
pub struct Inner {
    /// The database, for reads.
    pub db: AnyPool,
    /// The database's single writing connection (see [`Writer`]).
    pub writer: Writer,
    /// Where sealed documents and job outputs lie (the data directory, or the database).
    pub objects: super::store::objects::Objects,
    /// Configuration, secrets resolved.
    pub config: Config,
    /// Key sealing profiles.
    pub master_key: MasterKey,
    /// SHA-256 of the operator token.
    pub operator_token_hash: [u8; 32],
    /// Job state and progress changes.
    pub events: broadcast::Sender<JobEvent>,
    /// Wakes an idle worker when a job is queued.
    pub job_queued: Notify,
    /// Becomes true when the service starts shutting down.
    pub shutdown: watch::Receiver<bool>,
    /// Identifies this process's workers in the jobs table.
    pub instance_id: String,
    /// Prometheus registry.
    pub metrics: metrics_exporter_prometheus::PrometheusHandle,
    /// Transport operators shared by this process's workers (per display, profile version and eye position).
    pub transport_cache: Arc<eyekey_core::physics::transport::TransportCache>,
    /// Resolvability warnings per display id (geometry never changes, so they never go stale).
    pub display_warnings: std::sync::Mutex<std::collections::HashMap<String, Vec<String>>>,
}

impl std::ops::Deref for AppState {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        &self.0
    }
}

impl AppState {
    /// The data directory.
    pub fn data_dir(&self) -> &PathBuf {
        &self.config.data_dir
    }

    /// Broadcasts a job change (no receivers is fine). With PostgreSQL the change feed
    /// ([`super::feed`]) announces every change, from whichever process made it, so this does nothing.
    pub fn publish(&self, row: &JobRow) {
        if self.writer.backend() == super::store::Backend::Postgres {
            return;
        }
        let _ = self.events.send(JobEvent::of(row));
    }

    /// True once shutdown has begun.
    pub fn shutting_down(&self) -> bool {
        *self.shutdown.borrow()
    }
}

/// Resolves when `shutdown` becomes true (or its sender is gone).
pub async fn stopped(shutdown: &mut watch::Receiver<bool>) {
    // The guard `wait_for` returns is not `Send`; drop it here so callers' futures stay `Send`.
    let _ = shutdown.wait_for(|s| *s).await.map(|_| ());
}
