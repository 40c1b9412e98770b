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

mod backoff;
mod config;
mod error;
mod follow;
mod http;
mod install;
mod sse;
mod state;
mod sync;
mod track;

pub use backoff::Backoff;
pub use config::{ClientConfig, DisplayClientArgs};
pub use error::ClientError;
pub use follow::follow;
pub use http::newest_job;
pub use install::prepare_out_dir;
pub use sse::{SseEvent, SseParser};
pub use state::{read_state, ClientState, ShownJob};
pub use sync::{sync_once, SyncOutcome};
pub use track::{track_bundle, MAX_TRACKED_OFFSET_MM};

pub use crate::service::app::stop_signal;

/// The directory inside the output directory that holds the frames being shown.
pub const CURRENT_DIR: &str = "current";

/// The directory that holds what `current/` showed before the last install.
pub const PREVIOUS_DIR: &str = "previous";

/// The client's record of what it shows.
pub const STATE_FILE: &str = "state.json";

/// The simulated view written next to the frames with `--preview`.
pub const PREVIEW_FILE: &str = "preview.png";

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
