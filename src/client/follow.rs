//! `--follow`: keep `current/` on the newest bundle, woken by the server's event stream (or polling), with
//! backoff while the server is away.

use std::future::Future;
use std::time::Duration;

use futures::StreamExt as _;

use super::backoff::Backoff;
use super::config::ClientConfig;
use super::error::{error_chain, ClientError};
use super::http::{get, On404};
use super::install::prepare_out_dir;
use super::sse::SseParser;
use super::sync::{sync_once, SyncOutcome};

/// Why waiting for the next job ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Wake {
    /// One of this display's jobs succeeded.
    JobSucceeded,
    /// Time to re-list anyway.
    Resync,
    /// The server closed the stream (it is shutting down, say).
    StreamClosed,
}

/// Waits on `GET /v1/frames/events` for a `job_succeeded` event, at most `resync_interval`.
async fn wait_for_event(cfg: &ClientConfig) -> Result<Wake, ClientError> {
    let path = "/v1/frames/events";
    let url = cfg.url(path);
    let response = get(cfg, path, None, On404::NoApi).await?;
    let content_type = response
        .headers()
        .get(reqwest::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_string();
    if !content_type.starts_with("text/event-stream") {
        return Err(ClientError::Protocol {
            url,
            reason: format!("expected text/event-stream, got {content_type:?}"),
        });
    }
    tracing::debug!("listening for new bundles");
    let mut parser = SseParser::default();
    let mut stream = response.bytes_stream();
    let resync = tokio::time::sleep(cfg.resync_interval);
    tokio::pin!(resync);
    loop {
        tokio::select! {
            chunk = stream.next() => match chunk {
                None => return Ok(Wake::StreamClosed),
                Some(Err(e)) => return Err(ClientError::Unreachable { url, reason: error_chain(&e.without_url()) }),
                Some(Ok(bytes)) => {
                    if let Some(ev) = parser.push(&bytes).into_iter().find(|ev| ev.event == "job_succeeded") {
                        tracing::debug!(data = %ev.data, "a job succeeded");
                        return Ok(Wake::JobSucceeded);
                    }
                }
            },
            _ = &mut resync => return Ok(Wake::Resync),
        }
    }
}

/// Sleeps for `delay` unless `stop` completes first; true when stopped.
async fn sleep_or_stop(delay: Duration, stop: &mut (impl Future<Output = ()> + Unpin)) -> bool {
    tokio::select! {
        _ = tokio::time::sleep(delay) => false,
        _ = stop => true,
    }
}

fn report(outcome: &SyncOutcome) {
    match outcome {
        SyncOutcome::Installed { job_id, .. } => tracing::info!(job = %job_id, "{outcome}"),
        _ => tracing::debug!("{outcome}"),
    }
}

/// Keeps `current/` on the display's newest bundle until `stop` completes: catch up, then wait on the
/// server's event stream (or poll when it is unavailable), and again. While the server is unreachable it
/// retries with capped exponential backoff. Returns `Ok` when stopped, or the first error no retry can fix
/// (a refused token, a URL that is not an eyekey server, an unwritable output directory).
pub async fn follow(cfg: &ClientConfig, stop: impl Future<Output = ()>) -> Result<(), ClientError> {
    tokio::pin!(stop);
    prepare_out_dir(&cfg.out_dir)?;
    let mut backoff = Backoff::new(cfg.backoff_initial, cfg.backoff_max);
    // While set, the event stream failed and the client polls until then.
    let mut polling_until: Option<tokio::time::Instant> = None;
    let mut away = false;
    loop {
        let synced = tokio::select! {
            r = sync_once(cfg) => r,
            _ = &mut stop => return Ok(()),
        };
        match synced {
            Ok(outcome) => {
                if away {
                    tracing::info!(server = %cfg.server, "the server is back");
                    away = false;
                }
                backoff.reset();
                report(&outcome);
            }
            Err(e) if !e.is_retryable() => return Err(e),
            Err(e) => {
                let delay = backoff.next_delay();
                tracing::warn!(error = %error_chain(&e), retry_in_s = delay.as_secs_f64(), "sync failed; will retry");
                away = matches!(e, ClientError::Unreachable { .. } | ClientError::Status { .. });
                if sleep_or_stop(delay, &mut stop).await {
                    return Ok(());
                }
                continue;
            }
        }

        if polling_until.is_some_and(|t| tokio::time::Instant::now() < t) {
            if sleep_or_stop(cfg.poll_interval, &mut stop).await {
                return Ok(());
            }
            continue;
        }
        if polling_until.take().is_some() {
            tracing::info!("trying the event stream again");
        }
        let waited = tokio::select! {
            w = wait_for_event(cfg) => w,
            _ = &mut stop => return Ok(()),
        };
        match waited {
            Ok(Wake::JobSucceeded | Wake::Resync) => {}
            Ok(Wake::StreamClosed) => {
                // Usually the server shutting down; give it a moment before the next catch-up.
                if sleep_or_stop(cfg.backoff_initial, &mut stop).await {
                    return Ok(());
                }
            }
            Err(e) if !e.is_retryable() && !matches!(e, ClientError::NoApi { .. } | ClientError::Status { .. }) => {
                return Err(e)
            }
            // The server went away: the next catch-up notices and backs off.
            Err(ClientError::Unreachable { .. }) => {}
            // The server is up but its event stream is not (a proxy that buffers or blocks it, say): poll.
            Err(e) => {
                tracing::warn!(
                    error = %error_chain(&e),
                    poll_every_s = cfg.poll_interval.as_secs_f64(),
                    "the event stream is unavailable; polling instead"
                );
                polling_until = Some(tokio::time::Instant::now() + cfg.events_retry_after);
                if sleep_or_stop(cfg.poll_interval, &mut stop).await {
                    return Ok(());
                }
            }
        }
    }
}
