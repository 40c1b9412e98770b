//! `eyekey serve`: the networked service (docs/design.md §6).
//!
//! REST + JSON under `/v1` with an OpenAPI document (`/openapi.json`, Swagger UI at `/docs`); SQLite
//! (WAL) with embedded migrations; vision profiles sealed under a master key; a durable job queue in the
//! database whose workers run the encoder pipeline on the rayon pool; frame bundles served to each
//! display with its own token.
//!
//! Layout: [`config`] (flags and environment), [`app`] (build, run, shutdown), [`routes`] (one module
//! per resource), [`auth`] (operator and display tokens), [`crypto`], [`store`] (SQL), [`jobs`] (the
//! worker), [`error`] (the one HTTP error shape).

pub mod app;
pub mod auth;
pub mod config;
pub mod crypto;
pub mod error;
pub mod feed;
pub mod images;
pub mod jobs;
pub mod listener;
pub mod openapi;
pub mod retention;
pub mod routes;
pub mod sealed;
pub mod state;
pub mod store;

pub use app::{Application, ShutdownHandle, WorkerProcess};
pub use config::{Config, ServeArgs, WorkerArgs};
pub use jobs::try_execute_next_job;
pub use state::AppState;

/// Runs `eyekey serve` until SIGINT or SIGTERM.
pub async fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let app = Application::build(Config::from(args)).await?;
    // Said on stderr as well as in the log, so it is seen even without a log subscriber.
    eprintln!("eyekey serving on http://{} (API docs at /docs)", app.local_addr());
    if let Some(path) = app.operator_token_file() {
        eprintln!("eyekey operator token: in {}", path.display());
    }
    app.run_until_stopped().await
}

/// Runs `eyekey worker` (job workers, no API) until SIGINT or SIGTERM.
pub async fn worker(args: WorkerArgs) -> anyhow::Result<()> {
    let process = WorkerProcess::build(Config::from(args)).await?;
    eprintln!("eyekey worker running ({} worker(s))", process.state().config.workers);
    process.run_until_stopped().await
}
