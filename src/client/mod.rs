//! `eyekey display-client`: what runs next to a projector rig.
//!
//! It asks the service for its display's newest succeeded job (`GET /v1/frames/jobs`, with the display's
//! own token), downloads the bundle zip, verifies it with [`eyekey_core::bundle::read_bundle`] (sizes, SHA-256
//! checksums, geometry) and cross-checks it against the server's listing, then installs it into the output
//! directory:
//!
//! ```text
//! DIR/current/      frame_<n>.png (one per projector), barrier_mask.png, manifest.json[, preview.png]
//! DIR/previous/     what `current/` held before the last install
//! DIR/state.json    which job `current/` shows (never the token)
//! ```
//!
//! `current/` is never partial: the files are written and synced into a hidden staging directory inside
//! `DIR`, which then replaces `current/` by two renames (`current` → `previous`, staging → `current`). Between
//! the two renames `current/` is briefly absent, so a rig that finds it missing should retry the open.
//!
//! `--follow` keeps going: after each catch-up it waits on the server-sent events of
//! `GET /v1/frames/events`, falls back to polling when the event stream is unavailable, and retries with
//! exponential backoff (with jitter, capped) while the server is unreachable. Events missed while
//! disconnected are not replayed by the server, so every (re)connection starts by listing again.
//!
//! Only the newest job is ever shown: a job that finished after a newer one had already been installed is
//! skipped, since it holds an older document.
//!
//! Run one client per output directory: at start-up it removes the temporary entries a previous run left
//! behind there.

use std::future::Future;
use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::time::Duration;

use chrono::{DateTime, Utc};
use futures::StreamExt as _;
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use crate::service::error::ErrorBody;
use crate::service::routes::frames::{FrameJob, FrameJobList};
use eyekey_core::bundle::{self, BundleError, MANIFEST_FILE, MAX_BUNDLE_BYTES, MAX_FILE_BYTES, MAX_MANIFEST_BYTES};
use eyekey_core::physics::observer::Observer;
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportOptions};

/// The directory inside the output directory that holds the frames being shown.
pub const CURRENT_DIR: &str = "current";

/// The directory that holds what `current/` showed before the last install.
pub const PREVIOUS_DIR: &str = "previous";

/// The client's record of what it shows.
pub const STATE_FILE: &str = "state.json";

/// The simulated view written next to the frames with `--preview`.
pub const PREVIEW_FILE: &str = "preview.png";

/// Prefixes of the client's own temporary entries in the output directory, removed at start-up.
const DOWNLOAD_PREFIX: &str = ".download-";
const STAGING_PREFIX: &str = ".incoming-";

/// Largest bundle zip the client downloads: the reader's bundle limit plus the manifest and zip overhead.
const MAX_DOWNLOAD_BYTES: u64 = MAX_BUNDLE_BYTES + MAX_MANIFEST_BYTES + (1 << 20);

/// Time a listing request may take.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// Silence after which a connection counts as dead. The server sends an event-stream keep-alive every 15 s,
/// so an open event stream is never this quiet.
const READ_IDLE_TIMEOUT: Duration = Duration::from_secs(45);

/// Command-line options of `eyekey display-client`.
#[derive(clap::Args, Clone)]
pub struct DisplayClientArgs {
    /// Base URL of the eyekey service, e.g. `http://127.0.0.1:8080`.
    #[arg(long, env = "EYEKEY_SERVER_URL")]
    pub server: String,
    /// This display's access token, shown once when the display was registered. Prefer the environment
    /// variable: a command line is visible to other users of the machine.
    #[arg(long, env = "EYEKEY_DISPLAY_TOKEN", hide_env_values = true)]
    pub token: String,
    /// Output directory: `current/` (the frames to show), `previous/` and `state.json`.
    #[arg(long, env = "EYEKEY_CLIENT_OUT")]
    pub out: PathBuf,
    /// Install the newest bundle if it is not shown yet, then exit (0 also when there is nothing new).
    #[arg(long, conflicts_with = "follow")]
    pub once: bool,
    /// Keep running until Ctrl-C or SIGTERM, installing each new bundle as it succeeds (the default).
    #[arg(long)]
    pub follow: bool,
    /// Also write `current/preview.png`: what the person with this vision profile (JSON) sees of the frames.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Seconds between polls while the server's event stream is unavailable.
    #[arg(long, default_value_t = 5)]
    pub poll_secs: u64,
    /// Longest wait between reconnection attempts while the server is unreachable, seconds.
    #[arg(long, default_value_t = 60)]
    pub max_backoff_secs: u64,
}

impl std::fmt::Debug for DisplayClientArgs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DisplayClientArgs")
            .field("server", &self.server)
            .field("token", &"<redacted>")
            .field("out", &self.out)
            .field("once", &self.once)
            .field("follow", &self.follow)
            .field("preview", &self.preview)
            .field("poll_secs", &self.poll_secs)
            .field("max_backoff_secs", &self.max_backoff_secs)
            .finish()
    }
}

/// Why a sync did not install a bundle. [`ClientError::is_retryable`] tells a passing problem (the server is
/// away, a download broke) from one that needs a person (a wrong token or URL, an unwritable directory).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The configuration is unusable.
    #[error("{0}")]
    Config(String),
    /// No connection, a timeout, or a connection that broke off.
    #[error("cannot reach the eyekey server at {url}: {reason}")]
    Unreachable {
        /// The request's URL.
        url: String,
        /// The transport error and its causes.
        reason: String,
    },
    /// 401: the server does not know the token.
    #[error(
        "the server refused the display token (401 Unauthorized): check --token or EYEKEY_DISPLAY_TOKEN; \
         rotating the display's token replaces the old one"
    )]
    Unauthorised,
    /// 404 from an endpoint every eyekey server has: the URL does not point at one.
    #[error("{url} answered 404 Not Found: is --server the base URL of an eyekey service?")]
    NoApi {
        /// The request's URL.
        url: String,
    },
    /// 404 for a job that was listed a moment ago.
    #[error("job {job} is no longer offered to this display (404)")]
    JobGone {
        /// The job.
        job: Uuid,
    },
    /// Any other unexpected status.
    #[error("{url} answered {status}: {message}")]
    Status {
        /// The request's URL.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// The server's error message, or the start of its body.
        message: String,
    },
    /// An answer that is not what the API documents.
    #[error("unexpected answer from {url}: {reason}")]
    Protocol {
        /// The request's URL.
        url: String,
        /// What is wrong.
        reason: String,
    },
    /// The downloaded bundle failed verification.
    #[error("the bundle of job {job} failed verification")]
    Bundle {
        /// The job.
        job: Uuid,
        /// What the reader found.
        #[source]
        source: BundleError,
    },
    /// The downloaded bundle does not match what the server listed, or is too large.
    #[error("the bundle of job {job} does not match the server's listing: {reason}")]
    Mismatch {
        /// The job.
        job: Uuid,
        /// What differs.
        reason: String,
    },
    /// The preview could not be simulated.
    #[error("cannot simulate the preview: {0}")]
    Preview(String),
    /// A file operation in the output directory failed.
    #[error("cannot {op} {}", path.display())]
    Io {
        /// What was being done.
        op: &'static str,
        /// The path.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

impl ClientError {
    /// True when trying again later may succeed without anybody changing anything.
    pub fn is_retryable(&self) -> bool {
        match self {
            Self::Unreachable { .. }
            | Self::JobGone { .. }
            | Self::Protocol { .. }
            | Self::Bundle { .. }
            | Self::Mismatch { .. } => true,
            Self::Status { status, .. } => *status >= 500 || *status == 408 || *status == 429,
            Self::Config(_) | Self::Unauthorised | Self::NoApi { .. } | Self::Preview(_) | Self::Io { .. } => false,
        }
    }
}

fn io_err<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> ClientError + 'a {
    move |source| ClientError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

/// The error and its causes on one line (reqwest's own message rarely names the cause).
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let part = s.to_string();
        if !text.contains(&part) {
            text.push_str(": ");
            text.push_str(&part);
        }
        source = s.source();
    }
    text
}

/// Everything a sync needs. Its `Debug` hides the token.
#[derive(Clone)]
pub struct ClientConfig {
    /// Base URL of the service, without a trailing slash.
    pub server: String,
    /// The display's bearer token.
    pub token: String,
    /// Output directory.
    pub out_dir: PathBuf,
    /// The profile whose view is written to `current/preview.png`, if any.
    pub preview: Option<VisionProfile>,
    /// Time between polls while the event stream is unavailable.
    pub poll_interval: Duration,
    /// How long polling lasts before the event stream is tried again.
    pub events_retry_after: Duration,
    /// Re-list at least this often even while the event stream is quiet (events can be missed).
    pub resync_interval: Duration,
    /// First reconnection delay.
    pub backoff_initial: Duration,
    /// Longest reconnection delay.
    pub backoff_max: Duration,
    http: reqwest::Client,
}

impl std::fmt::Debug for ClientConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientConfig")
            .field("server", &self.server)
            .field("token", &"<redacted>")
            .field("out_dir", &self.out_dir)
            .field("preview", &self.preview.is_some())
            .field("poll_interval", &self.poll_interval)
            .field("events_retry_after", &self.events_retry_after)
            .field("resync_interval", &self.resync_interval)
            .field("backoff_initial", &self.backoff_initial)
            .field("backoff_max", &self.backoff_max)
            .finish()
    }
}

impl ClientConfig {
    /// A configuration with default timings (poll every 5 s, backoff 1 s doubling up to 60 s).
    pub fn new(server: &str, token: &str, out_dir: impl Into<PathBuf>) -> Result<Self, ClientError> {
        let url = reqwest::Url::parse(server)
            .map_err(|e| ClientError::Config(format!("--server {server:?} is not a URL: {e}")))?;
        if !matches!(url.scheme(), "http" | "https") || url.host_str().is_none() {
            return Err(ClientError::Config(format!(
                "--server {server:?} must be an http:// or https:// URL with a host"
            )));
        }
        if url.query().is_some() || url.fragment().is_some() {
            return Err(ClientError::Config(format!(
                "--server {server:?} must not have a query or fragment"
            )));
        }
        let token = token.trim();
        if token.is_empty() {
            return Err(ClientError::Config(
                "the display token is empty: pass --token or set EYEKEY_DISPLAY_TOKEN".into(),
            ));
        }
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(10))
            .read_timeout(READ_IDLE_TIMEOUT)
            .user_agent(concat!("eyekey-display-client/", env!("CARGO_PKG_VERSION")))
            .build()
            .map_err(|e| ClientError::Config(format!("cannot set up the HTTP client: {}", error_chain(&e))))?;
        Ok(Self {
            server: url.as_str().trim_end_matches('/').to_string(),
            token: token.to_string(),
            out_dir: out_dir.into(),
            preview: None,
            poll_interval: Duration::from_secs(5),
            events_retry_after: Duration::from_secs(60),
            resync_interval: Duration::from_secs(300),
            backoff_initial: Duration::from_secs(1),
            backoff_max: Duration::from_secs(60),
            http,
        })
    }

    /// The configuration of `eyekey display-client`; reads the `--preview` profile.
    pub fn from_args(a: &DisplayClientArgs) -> Result<Self, ClientError> {
        let mut cfg = Self::new(&a.server, &a.token, &a.out)?;
        if let Some(path) = &a.preview {
            let text = std::fs::read_to_string(path).map_err(io_err("read the --preview profile", path))?;
            let profile = VisionProfile::from_json(&text)
                .map_err(|e| ClientError::Config(format!("--preview {}: {e}", path.display())))?;
            cfg.preview = Some(profile);
        }
        cfg.poll_interval = Duration::from_secs(a.poll_secs.max(1));
        cfg.backoff_max = Duration::from_secs(a.max_backoff_secs.max(1));
        Ok(cfg)
    }

    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.server)
    }

    /// `DIR/current`.
    pub fn current_dir(&self) -> PathBuf {
        self.out_dir.join(CURRENT_DIR)
    }
}

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
fn write_state(out_dir: &Path, state: &ClientState) -> Result<(), ClientError> {
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

/// Creates the output directory and removes temporary entries an interrupted run left behind. Call it once
/// at start-up, before the first sync, not while another client may use the same directory.
pub fn prepare_out_dir(out_dir: &Path) -> Result<(), ClientError> {
    std::fs::create_dir_all(out_dir).map_err(io_err("create", out_dir))?;
    let entries = std::fs::read_dir(out_dir).map_err(io_err("list", out_dir))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with(DOWNLOAD_PREFIX) || name.starts_with(STAGING_PREFIX) || name.starts_with(".state-")) {
            continue;
        }
        let path = entry.path();
        let removed = if entry.file_type().is_ok_and(|t| t.is_dir()) {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if let Err(e) = removed {
            tracing::warn!(path = %path.display(), error = %e, "cannot remove a leftover temporary entry");
        }
    }
    Ok(())
}

/// What a 404 from a request means.
#[derive(Clone, Copy)]
enum On404 {
    /// The endpoint is missing: not an eyekey server.
    NoApi,
    /// The job went away between listing and download.
    JobGone(Uuid),
}

/// Sends an authorised GET and turns every non-2xx status into a [`ClientError`].
async fn get(
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

/// One catch-up: installs the display's newest succeeded job into `current/` unless it is already there.
///
/// Downloads the bundle zip into a temporary file in the output directory, verifies it
/// ([`eyekey_core::bundle::read_bundle`]: sizes, checksums, geometry) and checks it against the server's listing,
/// writes the preview if configured, and swaps the result into `current/`; updates `state.json` last.
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

/// Streams the job's `bundle.zip` into a temporary file in the output directory, refusing oversized ones.
async fn download_bundle(cfg: &ClientConfig, job: &FrameJob) -> Result<tempfile::NamedTempFile, ClientError> {
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

/// What [`install_bundle`] put into `current/`.
struct Installed {
    frames: u32,
    manifest_sha256: String,
    preview: Option<PathBuf>,
}

/// Verifies the zip, extracts the manifest and the files it lists into a staging directory, adds the
/// preview, and swaps the staging directory into `current/`.
fn install_bundle(
    zip_path: &Path,
    out_dir: &Path,
    job: &FrameJob,
    preview: Option<&VisionProfile>,
) -> Result<Installed, ClientError> {
    let (manifest, light_field) =
        bundle::read_bundle(zip_path).map_err(|source| ClientError::Bundle { job: job.id, source })?;
    let mismatch = |reason: String| ClientError::Mismatch { job: job.id, reason };

    // read_bundle has checked that every listed name is a plain file name and every file's checksum;
    // the copies are checked again as they are extracted, and against the server's own listing.
    let file = std::fs::File::open(zip_path).map_err(io_err("open", zip_path))?;
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| mismatch(format!("the zip cannot be reopened: {e}")))?;
    let staging = tempfile::Builder::new()
        .prefix(STAGING_PREFIX)
        .tempdir_in(out_dir)
        .map_err(io_err("create a staging directory in", out_dir))?;
    let mut wanted: Vec<(&str, Option<&str>, u64)> = vec![(MANIFEST_FILE, None, MAX_MANIFEST_BYTES)];
    wanted.extend(
        manifest
            .files
            .iter()
            .map(|f| (f.name.as_str(), Some(f.sha256.as_str()), f.bytes.min(MAX_FILE_BYTES))),
    );
    let mut extracted: Vec<(String, String, u64)> = Vec::with_capacity(wanted.len());
    for (name, expected_sha, limit) in wanted {
        let mut bytes = Vec::new();
        archive
            .by_name(name)
            .map_err(|e| mismatch(format!("{name}: {e}")))?
            .take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| mismatch(format!("{name}: {e}")))?;
        let sha = bundle::sha256_hex(&bytes);
        if expected_sha.is_some_and(|s| !s.eq_ignore_ascii_case(&sha)) || bytes.len() as u64 > limit {
            return Err(mismatch(format!("{name} changed while it was being extracted")));
        }
        let path = staging.path().join(name);
        write_synced(&path, &bytes)?;
        extracted.push((name.to_string(), sha, bytes.len() as u64));
    }
    for listed in &job.files {
        match extracted.iter().find(|(name, _, _)| *name == listed.name) {
            Some((_, sha, bytes)) if sha.eq_ignore_ascii_case(&listed.sha256) && *bytes == listed.bytes => {}
            Some(_) => {
                return Err(mismatch(format!(
                    "{} differs from the checksum and size the server lists",
                    listed.name
                )))
            }
            None => {
                return Err(mismatch(format!(
                    "the server lists {} but the bundle does not hold it",
                    listed.name
                )))
            }
        }
    }
    let manifest_sha256 = extracted[0].1.clone();

    let preview_path = match preview {
        Some(profile) => {
            let options = TransportOptions {
                sub_rays: 16,
                retina_oversample: 2,
                ..Default::default()
            };
            let observer = Observer::new(
                &manifest.display,
                profile,
                EyePosition::default(),
                &options,
                &eyekey_core::physics::transport::TransportCache::disabled(),
            )
            .map_err(|e| ClientError::Preview(e.to_string()))?;
            let picture = observer.picture(&observer.view(&light_field));
            eyekey_core::imaging::save_rgb_png(&picture, &staging.path().join(PREVIEW_FILE))
                .map_err(|e| ClientError::Preview(error_chain(&e)))?;
            Some(out_dir.join(CURRENT_DIR).join(PREVIEW_FILE))
        }
        None => None,
    };
    sync_dir(staging.path())?;

    // The swap: `previous` is dropped, `current` becomes `previous`, the staging directory becomes `current`.
    let current = out_dir.join(CURRENT_DIR);
    let previous = out_dir.join(PREVIOUS_DIR);
    if previous.exists() {
        std::fs::remove_dir_all(&previous).map_err(io_err("remove", &previous))?;
    }
    if current.exists() {
        std::fs::rename(&current, &previous).map_err(io_err("move aside", &current))?;
    }
    std::fs::rename(staging.path(), &current).map_err(io_err("rename the staging directory to", &current))?;
    // The directory now lives at `current`; stop the guard from removing its old path.
    let _ = staging.keep();
    sync_dir(out_dir)?;
    Ok(Installed {
        frames: manifest.n_frames,
        manifest_sha256,
        preview: preview_path,
    })
}

fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), ClientError> {
    let mut f = std::fs::File::create_new(path).map_err(io_err("create", path))?;
    f.write_all(bytes).map_err(io_err("write", path))?;
    f.sync_all().map_err(io_err("sync", path))
}

/// Makes a directory's entries durable (a rename is only safe once its directory is synced).
fn sync_dir(dir: &Path) -> Result<(), ClientError> {
    #[cfg(unix)]
    std::fs::File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(io_err("sync", dir))?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Exponential backoff with ±20 % jitter: `initial`, 2·`initial`, 4·`initial`, ... up to `max`.
#[derive(Clone, Debug)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    current: Option<Duration>,
}

impl Backoff {
    /// A backoff that starts at `initial` and never waits longer than `max`.
    pub fn new(initial: Duration, max: Duration) -> Self {
        Self {
            initial,
            max: max.max(initial),
            current: None,
        }
    }

    /// Forget the failures: the next delay is `initial` again.
    pub fn reset(&mut self) {
        self.current = None;
    }

    /// The delay before the next attempt, without jitter.
    pub fn next_base(&mut self) -> Duration {
        let next = match self.current {
            None => self.initial,
            Some(d) => (d * 2).min(self.max),
        };
        self.current = Some(next);
        next
    }

    /// The delay before the next attempt, with jitter so that many displays do not reconnect in step.
    pub fn next_delay(&mut self) -> Duration {
        let base = self.next_base();
        base.mul_f64(0.8 + 0.4 * rand::random::<f64>()).min(self.max)
    }
}

/// One server-sent event.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SseEvent {
    /// The `event:` field (`message` when absent).
    pub event: String,
    /// The `data:` lines, joined by newlines.
    pub data: String,
}

/// An incremental parser of a `text/event-stream` body: feed it chunks as they arrive.
#[derive(Debug, Default)]
pub struct SseParser {
    buffer: Vec<u8>,
    event: Option<String>,
    data: Vec<String>,
}

impl SseParser {
    /// Adds a chunk; returns the events it completes. Comments (keep-alives) and unknown fields are skipped.
    pub fn push(&mut self, chunk: &[u8]) -> Vec<SseEvent> {
        self.buffer.extend_from_slice(chunk);
        let mut events = Vec::new();
        while let Some(end) = self.buffer.iter().position(|&b| b == b'\n') {
            let raw: Vec<u8> = self.buffer.drain(..=end).collect();
            let line = String::from_utf8_lossy(&raw);
            let line = line.trim_end_matches(['\n', '\r']);
            if line.is_empty() {
                // A blank line dispatches the event; one without data is not dispatched (per the spec).
                let event = self.event.take().unwrap_or_else(|| "message".to_string());
                if !self.data.is_empty() {
                    events.push(SseEvent {
                        event,
                        data: self.data.join("\n"),
                    });
                }
                self.data.clear();
                continue;
            }
            if line.starts_with(':') {
                continue;
            }
            let (field, value) = line.split_once(':').unwrap_or((line, ""));
            let value = value.strip_prefix(' ').unwrap_or(value);
            match field {
                "event" => self.event = Some(value.to_string()),
                "data" => self.data.push(value.to_string()),
                _ => {}
            }
        }
        events
    }
}

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

/// Completes on Ctrl-C, or SIGTERM on Unix (what `docker stop` sends).
pub async fn stop_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = terminate => {}
    }
}

/// Runs `eyekey display-client`.
pub async fn run(args: DisplayClientArgs) -> anyhow::Result<()> {
    let cfg = ClientConfig::from_args(&args)?;
    if args.once {
        prepare_out_dir(&cfg.out_dir)?;
        println!("{}", sync_once(&cfg).await?);
        return Ok(());
    }
    eprintln!(
        "eyekey display client: following {} into {} (Ctrl-C stops)",
        cfg.server,
        cfg.current_dir().display()
    );
    follow(&cfg, stop_signal()).await?;
    eprintln!("eyekey display client: stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_event_stream_parser_handles_split_chunks_comments_and_crlf() {
        let mut p = SseParser::default();
        assert!(p.push(b": keep-alive\n\nevent: job_succ").is_empty());
        assert!(p.push(b"eeded\r\ndata: {\"id\":").is_empty());
        let events = p.push(b" 1}\r\n\r\ndata: a\ndata: b\n\n");
        assert_eq!(
            events,
            vec![
                SseEvent {
                    event: "job_succeeded".into(),
                    data: "{\"id\": 1}".into()
                },
                SseEvent {
                    event: "message".into(),
                    data: "a\nb".into()
                },
            ]
        );
    }

    #[test]
    fn the_backoff_doubles_up_to_its_cap_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(500));
        let delays: Vec<u128> = (0..5).map(|_| b.next_base().as_millis()).collect();
        assert_eq!(delays, vec![100, 200, 400, 500, 500]);
        b.reset();
        assert_eq!(b.next_base(), Duration::from_millis(100));
        // Jitter stays within ±20 % and never exceeds the cap.
        for _ in 0..100 {
            let d = b.next_delay();
            assert!(
                d >= Duration::from_millis(80) && d <= Duration::from_millis(500),
                "{d:?}"
            );
        }
    }

    #[test]
    fn a_server_url_must_be_http_with_a_host_and_the_token_must_not_be_empty() {
        assert!(ClientConfig::new("ftp://x", "t", "/tmp/x").is_err());
        assert!(ClientConfig::new("not a url", "t", "/tmp/x").is_err());
        assert!(ClientConfig::new("http://127.0.0.1:1/", " ", "/tmp/x").is_err());
        let c = ClientConfig::new("http://127.0.0.1:8080/", "secret", "/tmp/x").unwrap();
        assert_eq!(c.url("/v1/frames/jobs"), "http://127.0.0.1:8080/v1/frames/jobs");
        assert!(!format!("{c:?}").contains("secret"));
    }

    #[test]
    fn only_problems_of_the_moment_are_retried() {
        let url = String::from("http://x");
        assert!(ClientError::Unreachable {
            url: url.clone(),
            reason: String::new()
        }
        .is_retryable());
        assert!(ClientError::Status {
            url: url.clone(),
            status: 503,
            message: String::new()
        }
        .is_retryable());
        assert!(!ClientError::Status {
            url: url.clone(),
            status: 400,
            message: String::new()
        }
        .is_retryable());
        assert!(!ClientError::Unauthorised.is_retryable());
        assert!(!ClientError::NoApi { url }.is_retryable());
    }
}
