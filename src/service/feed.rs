//! The change feed of a PostgreSQL deployment: every process LISTENs on `eyekey_jobs`, to which a trigger
//! on `jobs` (migration 5) sends each change of a job when it commits. The feed turns them into this
//! process's [`JobEvent`]s, so a job's event stream and a display's bundle stream follow jobs run by
//! workers in other processes, and wakes an idle worker when a job is queued anywhere.
//!
//! With SQLite there is one process, which publishes its own changes as it makes them
//! ([`AppState::publish`]); with PostgreSQL the feed is the only source, so no change is announced twice.

use std::time::Duration;

use serde::Deserialize;
use sqlx::postgres::PgListener;

use super::state::{AppState, JobEvent};
use super::store::ids::JobId;
use super::store::jobs::JobState;

/// The channel the `jobs` trigger notifies.
pub const CHANNEL: &str = "eyekey_jobs";

/// A notification's payload, as the trigger builds it.
#[derive(Debug, Deserialize)]
struct Change {
    id: String,
    display_id: String,
    state: String,
    progress: f64,
}

/// Parses a notification's payload into an event (`None` for one this version does not understand).
fn event_of(payload: &str) -> Option<JobEvent> {
    let c: Change = serde_json::from_str(payload).ok()?;
    Some(JobEvent {
        job_id: c.id.parse::<JobId>().ok()?,
        display_id: c.display_id,
        state: JobState::parse(&c.state)?,
        progress: c.progress,
    })
}

/// Listens until shutdown, reconnecting with backoff (0.5 s doubling to 10 s) when the connection drops.
/// While it is down, event streams still re-read their job every second and idle workers poll.
pub fn spawn(state: &AppState, url: String) -> tokio::task::JoinHandle<()> {
    let state = state.clone();
    tokio::spawn(async move {
        let mut shutdown = state.shutdown.clone();
        let mut wait = Duration::from_millis(500);
        while !state.shutting_down() {
            let listened = async {
                let mut listener = PgListener::connect(&url).await?;
                listener.listen(CHANNEL).await?;
                tracing::info!(channel = CHANNEL, "following job changes");
                loop {
                    // `try_recv` gives `None` when the connection was lost (notifications may have been
                    // missed); reconnect then.
                    let Some(n) = listener.try_recv().await? else {
                        return Ok::<(), sqlx::Error>(());
                    };
                    wait = Duration::from_millis(500);
                    if let Some(event) = event_of(n.payload()) {
                        if event.state == JobState::Queued {
                            state.job_queued.notify_one();
                        }
                        let _ = state.events.send(event);
                    }
                }
            };
            tokio::select! {
                r = listened => match r {
                    Ok(()) => tracing::warn!("the job change feed lost its connection; reconnecting"),
                    Err(e) => tracing::warn!(error = %e, retry_in = ?wait, "the job change feed failed; reconnecting"),
                },
                _ = super::state::stopped(&mut shutdown) => return,
            }
            tokio::select! {
                _ = tokio::time::sleep(wait) => {}
                _ = super::state::stopped(&mut shutdown) => return,
            }
            wait = (wait * 2).min(Duration::from_secs(10));
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_notification_becomes_an_event_and_garbage_is_ignored() {
        let id = JobId::new_v4();
        let payload = format!(r#"{{"id": "{id}", "display_id": "d", "state": "succeeded", "progress": 1.0}}"#);
        let ev = event_of(&payload).unwrap();
        assert_eq!(
            (ev.job_id, ev.display_id.as_str(), ev.state, ev.progress),
            (id, "d", JobState::Succeeded, 1.0)
        );
        assert!(event_of("{}").is_none());
        assert!(event_of(&payload.replace("succeeded", "exploded")).is_none());
    }
}
