//! Requests to the service: the authorised GET that maps statuses to [`ClientError`]s, the job listing and
//! the bundle download.

use std::io::Write as _;
use std::time::Duration;

use futures::StreamExt as _;

use super::config::ClientConfig;
use super::error::{error_chain, io_err, ClientError};
use super::install::DOWNLOAD_PREFIX;
use crate::service::error::ErrorBody;
use crate::service::routes::frames::{FrameJob, FrameJobList};
use eyekey_core::bundle::{MAX_BUNDLE_BYTES, MAX_MANIFEST_BYTES};
use uuid::Uuid;

/// Largest bundle zip the client downloads: the reader's bundle limit plus the manifest and zip overhead.
const MAX_DOWNLOAD_BYTES: u64 = MAX_BUNDLE_BYTES + MAX_MANIFEST_BYTES + (1 << 20);

/// Time a listing request may take.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// What a 404 from a request means.
#[derive(Clone, Copy)]
pub(super) enum On404 {
    /// The endpoint is missing: not an eyekey server.
    NoApi,
    /// The job went away between listing and download.
    JobGone(Uuid),
}

/// Sends an authorised GET and turns every non-2xx status into a [`ClientError`].
pub(super) async fn get(
    cfg: &ClientConfig,
    path: &str,
    timeout: Option<Duration>,
    on_404: On404,
) -> Result<reqwest::Response, ClientError> {
    let url = cfg.url(path);
    let mut request = cfg.http.get(&url).bearer_auth(&cfg.token);
    if let Some(t) = timeout {
        request = request.timeout(t);
    }
    let response = request.send().await.map_err(|e| ClientError::Unreachable {
        url: url.clone(),
        reason: error_chain(&e.without_url()),
    })?;
    let status = response.status();
    if status.is_success() {
        return Ok(response);
    }
    Err(match status.as_u16() {
        401 => ClientError::Unauthorised,
        404 => match on_404 {
            On404::NoApi => ClientError::NoApi { url },
            On404::JobGone(job) => ClientError::JobGone { job },
        },
        code => {
            // The service's error shape when it is one, else the start of whatever came back (a proxy page).
            let body = response.text().await.unwrap_or_default();
            let message = match serde_json::from_str::<ErrorBody>(&body) {
                Ok(e) => e.error.message,
                Err(_) => body.chars().take(200).collect::<String>().trim().to_string(),
            };
            ClientError::Status {
                url,
                status: code,
                message,
            }
        }
    })
}

/// The display's newest succeeded job, if any.
pub async fn newest_job(cfg: &ClientConfig) -> Result<Option<FrameJob>, ClientError> {
    let path = "/v1/frames/jobs?limit=1";
    let response = get(cfg, path, Some(REQUEST_TIMEOUT), On404::NoApi).await?;
    let list: FrameJobList = response.json().await.map_err(|e| ClientError::Protocol {
        url: cfg.url(path),
        reason: format!("not a frame-job list: {}", error_chain(&e.without_url())),
    })?;
    // The list is newest first.
    Ok(list.items.into_iter().next())
}

/// Streams the job's `bundle.zip` into a temporary file in the output directory, refusing oversized ones.
pub(super) async fn download_bundle(
    cfg: &ClientConfig,
    job: &FrameJob,
) -> Result<tempfile::NamedTempFile, ClientError> {
    let path = format!("/v1/frames/jobs/{}/bundle.zip", job.id);
    let url = cfg.url(&path);
    let response = get(cfg, &path, None, On404::JobGone(job.id)).await?;
    if response.content_length().is_some_and(|n| n > MAX_DOWNLOAD_BYTES) {
        return Err(ClientError::Mismatch {
            job: job.id,
            reason: format!("the zip is larger than the limit of {MAX_DOWNLOAD_BYTES} bytes"),
        });
    }
    let mut file = tempfile::Builder::new()
        .prefix(DOWNLOAD_PREFIX)
        .suffix(".zip")
        .tempfile_in(&cfg.out_dir)
        .map_err(io_err("create a temporary file in", &cfg.out_dir))?;
    let mut stream = response.bytes_stream();
    let mut total = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| ClientError::Unreachable {
            url: url.clone(),
            reason: error_chain(&e.without_url()),
        })?;
        total += chunk.len() as u64;
        if total > MAX_DOWNLOAD_BYTES {
            return Err(ClientError::Mismatch {
                job: job.id,
                reason: format!("the zip is larger than the limit of {MAX_DOWNLOAD_BYTES} bytes"),
            });
        }
        file.write_all(&chunk).map_err(io_err("write", file.path()))?;
    }
    file.as_file().sync_all().map_err(io_err("sync", file.path()))?;
    Ok(file)
}
