//! Building and running the service: secrets, database, router, workers, graceful shutdown.

use eyekey_core::physics::transport::TransportCache;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context as _;
use axum::extract::DefaultBodyLimit;
use axum::http::StatusCode;
use axum::Router;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, watch, Notify};
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::timeout::TimeoutLayer;
use tower_http::trace::TraceLayer;
use utoipa::OpenApi as _;
use utoipa_swagger_ui::SwaggerUi;

use super::config::Config;
use super::crypto::{generate_token, token_hash, MasterKey};
use super::error::{json_error_bodies, panic_response};
use super::openapi::ApiDoc;
use super::routes;
use super::state::{AppState, Inner};
use super::{jobs, store};

/// File in the data directory holding the generated operator token.
pub const OPERATOR_TOKEN_FILE: &str = "operator-token";
/// File in the data directory holding the generated master key.
pub const MASTER_KEY_FILE: &str = "master.key";

/// A built service: listening, migrated, not yet serving.
pub struct Application {
    listener: TcpListener,
    router: Router,
    state: AppState,
    shutdown: ShutdownHandle,
    operator_token_file: Option<PathBuf>,
    tls: Option<tokio_rustls::TlsAcceptor>,
    /// SIGINT and SIGTERM, listened for since the process was built: one sent as soon as it says it is serving
    /// stops it gracefully instead of killing it.
    stop: StopSignal,
    /// Held while this process uses the data directory.
    _lock: std::fs::File,
}

/// Starts a graceful shutdown of an [`Application`] from elsewhere (signals do it too).
#[derive(Clone)]
pub struct ShutdownHandle(Arc<watch::Sender<bool>>);

impl ShutdownHandle {
    /// Begins shutdown: stop accepting requests and claiming jobs, re-queue running jobs.
    pub fn shutdown(&self) {
        self.0.send_replace(true);
    }
}

impl Application {
    /// Resolves secrets, opens and migrates the database, binds the listener (port 0 picks a free port).
    pub async fn build(config: Config) -> anyhow::Result<Self> {
        let opened = open(config, Role::Api).await?;
        let config = &opened.state.config;
        let tls = match &config.tls {
            Some((cert, key)) => Some(super::listener::tls_acceptor(cert, key)?),
            None if !config.bind.ip().is_loopback() && !config.insecure_http => anyhow::bail!(
                "refusing to serve plain HTTP on {}, which is not a loopback address: give --tls-cert and \
                 --tls-key, or --insecure-http behind a TLS-terminating proxy on this host",
                config.bind
            ),
            None => None,
        };
        let listener = TcpListener::bind(config.bind)
            .await
            .with_context(|| format!("binding {}", config.bind))?;
        let state = opened.state;
        // Before any worker or request: seal what an older version stored in clear, then sweep leftovers
        // (files under the data directory; with PostgreSQL there are neither).
        if matches!(state.objects, store::objects::Objects::Dir(_)) {
            let (docs, jobs) = super::retention::seal_unsealed(&state)
                .await
                .context("sealing stored data")?;
            if docs + jobs > 0 {
                tracing::info!(documents = docs, jobs, "sealed data stored before sealing");
            }
            super::retention::sweep(&state)
                .await
                .context("sweeping leftovers in the data directory")?;
        } else {
            let removed = super::retention::sweep_objects(&state)
                .await
                .context("sweeping the objects of deleted data")?;
            if removed > 0 {
                tracing::info!(objects = removed, "removed the objects of deleted data");
            }
        }
        let router = router(state.clone());
        Ok(Self {
            listener,
            router,
            state,
            shutdown: opened.shutdown,
            operator_token_file: opened.operator_token_file,
            tls,
            stop: Box::pin(stop_signal()),
            _lock: opened.lock,
        })
    }

    /// The port the listener is bound to.
    pub fn port(&self) -> u16 {
        self.local_addr().port()
    }

    /// The address the listener is bound to.
    pub fn local_addr(&self) -> SocketAddr {
        self.listener.local_addr().unwrap_or(self.state.config.bind)
    }

    /// `https` when TLS is configured, else `http`.
    pub fn scheme(&self) -> &'static str {
        if self.tls.is_some() {
            "https"
        } else {
            "http"
        }
    }

    /// The shared state (the tests drive the worker step with it).
    pub fn state(&self) -> AppState {
        self.state.clone()
    }

    /// The file the operator token was read from or generated into; `None` when it was configured.
    pub fn operator_token_file(&self) -> Option<&Path> {
        self.operator_token_file.as_deref()
    }

    /// A handle that stops the service.
    pub fn shutdown_handle(&self) -> ShutdownHandle {
        self.shutdown.clone()
    }

    /// Serves requests and runs the workers until SIGINT, SIGTERM or [`ShutdownHandle::shutdown`].
    ///
    /// On shutdown: the listener stops accepting, event streams end, in-flight requests finish, workers
    /// stop claiming, and running jobs are cancelled and re-queued (their attempt not counted) within the
    /// configured grace period; a job still running after it is picked up again when its lease expires.
    pub async fn run_until_stopped(self) -> anyhow::Result<()> {
        let scheme = self.scheme();
        let Self {
            listener,
            router,
            state,
            shutdown,
            tls,
            stop,
            _lock: lock,
            ..
        } = self;
        let address = listener.local_addr()?;
        tracing::info!(%address, scheme, workers = state.config.workers, "eyekey serving");
        tracing::info!(
            "operator console at {scheme}://{address}/console (sign in with the operator token), API documentation at {scheme}://{address}/docs"
        );
        let feed = spawn_feed(&state);
        let mut workers = jobs::spawn_workers(&state, state.config.workers);
        let retention = super::retention::spawn_retention(&state);

        shut_down_on(stop, &shutdown);
        super::listener::serve(
            listener,
            router,
            tls,
            super::listener::ConnectionLimits {
                header_timeout: state.config.limits.header_read_timeout,
                idle_timeout: state.config.limits.idle_timeout,
                max_connections: state.config.limits.max_connections,
            },
            state.shutdown.clone(),
            state.config.queue.shutdown_grace,
        )
        .await
        .context("serving HTTP")?;

        shutdown.shutdown();
        drain_workers(&state, &mut workers).await;
        retention.abort();
        if let Some(feed) = feed {
            feed.abort();
        }
        state.db.close().await;
        state.writer.0.close().await;
        drop(lock);
        tracing::info!("eyekey stopped");
        Ok(())
    }
}

/// Which kind of process is opening the service's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// `eyekey serve`: applies the migrations.
    Api,
    /// `eyekey worker`: waits until an API process has applied them.
    Worker,
}

/// What [`open`] prepared: the shared state and what the process must hold while it runs.
struct Opened {
    state: AppState,
    shutdown: ShutdownHandle,
    operator_token_file: Option<PathBuf>,
    lock: std::fs::File,
}

/// The start of every process: the data directory and its lock, the database (migrated by an API process,
/// awaited by a worker), the secrets, and the shared state.
async fn open(config: Config, role: Role) -> anyhow::Result<Opened> {
    let data_dir = config.data_dir.clone();
    let location = config.database_location();
    let backend = location.backend();
    let subdirs: &[&str] = match backend {
        store::Backend::Sqlite => &["", "documents", "jobs"],
        store::Backend::Postgres => &[""],
    };
    for sub in subdirs {
        tokio::fs::create_dir_all(data_dir.join(sub))
            .await
            .with_context(|| format!("creating {}", data_dir.join(sub).display()))?;
    }
    restrict_dir(&data_dir);
    let lock = lock_data_dir(&data_dir)?;

    let (operator_token, operator_token_file) = match &config.operator_token {
        Some(t) => (t.clone(), None),
        // A worker serves no request: no operator token to keep.
        None if role == Role::Worker => (generate_token("eko_"), None),
        None => {
            let path = data_dir.join(OPERATOR_TOKEN_FILE);
            let token = read_or_create_secret(&path, "operator token", || generate_token("eko_"))?;
            (token, Some(path))
        }
    };
    if role == Role::Worker && config.master_key_hex.is_none() && !data_dir.join(MASTER_KEY_FILE).exists() {
        anyhow::bail!(
            "a worker needs the master key the API processes use: give it with EYEKEY_MASTER_KEY (or put it in \
             {}); a worker never makes one",
            data_dir.join(MASTER_KEY_FILE).display()
        );
    }
    let (db, writer) = match role {
        Role::Api => {
            let (db, writer) = store::connect(&location)
                .await
                .with_context(|| format!("opening the database {location}"))?;
            store::migrate(&writer).await.context("applying database migrations")?;
            (db, writer)
        }
        Role::Worker => wait_for_schema(&location).await,
    };
    let master_key = match &config.master_key_hex {
        Some(k) => MasterKey::from_hex(k).context("the master key given by --master-key or EYEKEY_MASTER_KEY")?,
        None => {
            let path = data_dir.join(MASTER_KEY_FILE);
            if !path.exists() && store::holds_master_key_check(&writer).await? {
                anyhow::bail!(
                    "the database {location} holds data sealed under a master key, and {} is missing: give \
                     the key every eyekey process shares with EYEKEY_MASTER_KEY (or restore the file from its \
                     backup); a new key could not open what is stored",
                    path.display()
                );
            }
            let text = read_or_create_secret(&path, "master key", MasterKey::generate_hex)?;
            MasterKey::from_hex(&text).with_context(|| format!("the master key in {}", path.display()))?
        }
    };
    store::check_master_key(&writer, &master_key).await?;
    tracing::info!(database = %location, "database ready");

    let objects = match backend {
        store::Backend::Sqlite => store::objects::Objects::Dir(data_dir.clone()),
        store::Backend::Postgres => store::objects::Objects::Database(writer.clone()),
    };
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let state = AppState(Arc::new(Inner {
        db,
        writer,
        objects,
        operator_token_hash: token_hash(&operator_token),
        master_key,
        events: broadcast::channel(1024).0,
        job_queued: Notify::new(),
        shutdown: shutdown_rx,
        instance_id: uuid::Uuid::new_v4().to_string(),
        metrics: routes::metrics::recorder(),
        transport_cache: Arc::new(TransportCache::new(config.transport_cache_bytes)),
        display_warnings: Default::default(),
        config,
    }));
    Ok(Opened {
        state,
        shutdown: ShutdownHandle(Arc::new(shutdown_tx)),
        operator_token_file,
        lock,
    })
}

/// Connects and waits until every migration this binary knows is applied (by an API process), retrying
/// with backoff (0.5 s doubling to 10 s) while the database is unreachable or behind, and saying why.
async fn wait_for_schema(location: &store::Location) -> (sqlx::AnyPool, store::Writer) {
    let mut wait = std::time::Duration::from_millis(500);
    loop {
        let why = match store::connect(location).await {
            Ok((db, writer)) => match store::migrations_applied(&db).await {
                // The first API process writes the master key's sentinel right after migrating; a worker
                // only ever checks it, so a worker can never lock the API processes out with another key.
                Ok(true) => match store::holds_master_key_check(&writer).await {
                    Ok(true) => return (db, writer),
                    Ok(false) => "no API process (eyekey serve) has started on it yet".to_string(),
                    Err(e) => format!("{e}"),
                },
                Ok(false) => "an API process (eyekey serve) has not yet applied every migration".to_string(),
                Err(e) if e.as_database_error().is_some() => {
                    format!("no schema yet (eyekey serve applies it): {e}")
                }
                Err(e) => format!("{e}"),
            },
            Err(e) => format!("cannot connect: {e}"),
        };
        tracing::info!(database = %location, reason = %why, retry_in = ?wait, "waiting for the database");
        tokio::time::sleep(wait).await;
        wait = (wait * 2).min(std::time::Duration::from_secs(10));
    }
}

/// `eyekey worker`: job workers with no API, on the database of `--database-url`.
pub struct WorkerProcess {
    state: AppState,
    shutdown: ShutdownHandle,
    /// As [`Application`]'s.
    stop: StopSignal,
    _lock: std::fs::File,
}

impl WorkerProcess {
    /// Opens the state; waits for the database and its schema (it never migrates: API processes do).
    pub async fn build(config: Config) -> anyhow::Result<Self> {
        anyhow::ensure!(config.workers > 0, "a worker process needs --workers 1 or more");
        anyhow::ensure!(
            config.database_location().backend() == store::Backend::Postgres,
            "eyekey worker runs beside API processes on a shared PostgreSQL database: give --database-url \
             postgres://… (with SQLite, the workers run inside eyekey serve)"
        );
        let opened = open(config, Role::Worker).await?;
        Ok(Self {
            state: opened.state,
            shutdown: opened.shutdown,
            stop: Box::pin(stop_signal()),
            _lock: opened.lock,
        })
    }

    /// The shared state.
    pub fn state(&self) -> AppState {
        self.state.clone()
    }

    /// A handle that stops the workers.
    pub fn shutdown_handle(&self) -> ShutdownHandle {
        self.shutdown.clone()
    }

    /// Runs the workers until SIGINT, SIGTERM or [`ShutdownHandle::shutdown`]; on shutdown running jobs are
    /// re-queued without counting the attempt, as in `serve`.
    pub async fn run_until_stopped(self) -> anyhow::Result<()> {
        let Self {
            state,
            shutdown,
            stop,
            _lock,
        } = self;
        tracing::info!(workers = state.config.workers, instance = %state.instance_id, "eyekey worker running");
        let feed = spawn_feed(&state);
        let mut workers = jobs::spawn_workers(&state, state.config.workers);
        shut_down_on(stop, &shutdown);
        let mut stopped = state.shutdown.clone();
        crate::service::state::stopped(&mut stopped).await;
        drain_workers(&state, &mut workers).await;
        if let Some(feed) = feed {
            feed.abort();
        }
        state.db.close().await;
        state.writer.0.close().await;
        tracing::info!("eyekey worker stopped");
        Ok(())
    }
}

/// Starts the change feed of a PostgreSQL deployment (see [`super::feed`]).
fn spawn_feed(state: &AppState) -> Option<tokio::task::JoinHandle<()>> {
    match state.config.database_location() {
        store::Location::Postgres(url) => Some(super::feed::spawn(state, url)),
        store::Location::Sqlite(_) => None,
    }
}

/// Waits up to the shutdown grace for the workers to re-queue their jobs, then aborts them.
async fn drain_workers(state: &AppState, workers: &mut tokio::task::JoinSet<()>) {
    let grace = state.config.queue.shutdown_grace;
    let drained = tokio::time::timeout(grace, async { while workers.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        tracing::warn!(
            ?grace,
            "workers did not stop in time; their jobs will be re-claimed after the lease"
        );
        workers.abort_all();
    }
}

/// The full HTTP stack: routes, metrics, documentation, limits and error shaping.
fn router(state: AppState) -> Router {
    let limits = &state.config.limits;
    Router::new()
        .merge(routes::router(limits.max_document_bytes))
        .merge(SwaggerUi::new("/docs").url("/openapi.json", ApiDoc::openapi()))
        .route_layer(axum::middleware::from_fn(routes::metrics::track_http))
        .layer(DefaultBodyLimit::max(limits.max_body_bytes))
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            limits.request_timeout,
        ))
        .layer(axum::middleware::from_fn_with_state(state.clone(), reject_oversize))
        .layer(CatchPanicLayer::custom(panic_response))
        .layer(axum::middleware::map_response(json_error_bodies))
        // Every request gets an `x-request-id` (the client's, or a new UUID), echoed in the response and
        // recorded on the request's log span, so a log line can be matched to the request that caused it.
        .layer(PropagateRequestIdLayer::x_request_id())
        .layer(TraceLayer::new_for_http().make_span_with(|request: &axum::http::Request<_>| {
            let id = request.headers().get("x-request-id").and_then(|v| v.to_str().ok()).unwrap_or("-");
            tracing::info_span!("request", method = %request.method(), uri = %request.uri().path(), request_id = %id)
        }))
        .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
        .with_state(state)
}

/// Answers 413 at once when a request's `Content-Length` exceeds the limit of its route (uploads:
/// `max_document_bytes`; everything else: `max_body_bytes`), before a byte of the body is read.
async fn reject_oversize(
    axum::extract::State(state): axum::extract::State<AppState>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::response::IntoResponse as _;
    let limits = &state.config.limits;
    let upload = request.method() == axum::http::Method::POST && request.uri().path() == "/v1/documents";
    let limit = if upload {
        limits.max_document_bytes
    } else {
        limits.max_body_bytes
    } as u64;
    let declared = request
        .headers()
        .get(axum::http::header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    match declared {
        Some(len) if len > limit => super::error::ApiError::TooLarge {
            field: Some("body".into()),
            message: format!("the body's {len} bytes exceed the limit of {limit} bytes"),
        }
        .into_response(),
        _ => next.run(request).await,
    }
}

/// [`stop_signal`], held until it is awaited.
type StopSignal = std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>;

/// Shuts the process down (`shutdown`) when `stop` completes.
fn shut_down_on(stop: StopSignal, shutdown: &ShutdownHandle) {
    let shutdown = shutdown.clone();
    tokio::spawn(async move {
        stop.await;
        tracing::info!("shutdown signal received");
        shutdown.shutdown();
    });
}

/// Completes on Ctrl-C (SIGINT), or SIGTERM on Unix (what `docker stop` sends). The service and the display
/// client both stop on it. On Unix the signals are listened for from this call on (call it within the runtime),
/// not from the first poll: a signal that arrives in between is kept instead of taking its default action,
/// which kills the process.
pub fn stop_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    #[cfg(unix)]
    let (interrupt, terminate) = {
        use tokio::signal::unix::{signal, SignalKind};
        (
            signal(SignalKind::interrupt()).ok(),
            signal(SignalKind::terminate()).ok(),
        )
    };
    async move {
        #[cfg(unix)]
        {
            let wait = |s: Option<tokio::signal::unix::Signal>| async move {
                match s {
                    Some(mut s) => {
                        s.recv().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            };
            tokio::select! {
                _ = wait(interrupt) => {}
                _ = wait(terminate) => {}
            }
        }
        #[cfg(not(unix))]
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// File in the data directory that a running server holds locked.
pub const LOCK_FILE: &str = "eyekey.lock";

/// How long a starting server waits for the data directory's lock before refusing: a server stopped a moment
/// ago may still be letting it go (its last tasks dropping their hold, or a child process forked by another
/// thread holding a copy of the descriptor until it execs).
const LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Takes the data directory's lock (an advisory lock on `eyekey.lock`, released when the process ends,
/// however it ends), so a second server cannot open the same data; waits up to [`LOCK_WAIT`] for it.
fn lock_data_dir(data_dir: &Path) -> anyhow::Result<std::fs::File> {
    let start = std::time::Instant::now();
    loop {
        match try_lock_data_dir(data_dir) {
            Err(e) if e.is::<Held>() && start.elapsed() < LOCK_WAIT => {
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
            Err(e) if e.is::<Held>() => {
                let path = data_dir.join(LOCK_FILE);
                anyhow::bail!(
                    "another eyekey server is using {} (it holds {}); stop it first, or give this one its own \
                     --data-dir",
                    data_dir.display(),
                    path.display()
                );
            }
            other => return other,
        }
    }
}

/// The data directory's lock is held by another open file (another server).
#[derive(Debug, thiserror::Error)]
#[error("the data directory's lock is held")]
struct Held;

/// One attempt at [`lock_data_dir`]: [`Held`] when another holds the lock.
fn try_lock_data_dir(data_dir: &Path) -> anyhow::Result<std::fs::File> {
    let path = data_dir.join(LOCK_FILE);
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::io::AsRawFd as _;
        // SAFETY: flock on a file descriptor this function owns; the lock goes with the descriptor.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::WouldBlock {
                return Err(Held.into());
            }
            return Err(anyhow::Error::new(e).context(format!("locking {}", path.display())));
        }
    }
    Ok(file)
}

/// Reads a secret file, or creates it (mode 0600) with a generated value. Logs the path, never the value.
fn read_or_create_secret(path: &Path, what: &str, generate: impl FnOnce() -> String) -> anyhow::Result<String> {
    match std::fs::read_to_string(path) {
        Ok(text) => {
            warn_if_readable_by_others(path);
            let value = text.trim().to_string();
            anyhow::ensure!(!value.is_empty(), "{} is empty", path.display());
            tracing::info!(path = %path.display(), "using the {what} from this file");
            Ok(value)
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let value = generate();
            write_private(path, &value).with_context(|| format!("writing {}", path.display()))?;
            tracing::info!(path = %path.display(), "generated a new {what} into this file (mode 0600)");
            Ok(value)
        }
        Err(e) => Err(anyhow::Error::new(e).context(format!("reading {}", path.display()))),
    }
}

fn write_private(path: &Path, value: &str) -> std::io::Result<()> {
    use std::io::Write as _;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt as _;
        options.mode(0o600);
    }
    let mut file = options.open(path)?;
    file.write_all(value.as_bytes())?;
    file.write_all(b"\n")?;
    file.sync_all()
}

fn warn_if_readable_by_others(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        if let Ok(meta) = std::fs::metadata(path) {
            if meta.permissions().mode() & 0o077 != 0 {
                tracing::warn!(path = %path.display(), "secret file is readable by other users; chmod 600 it");
            }
        }
    }
    #[cfg(not(unix))]
    let _ = path;
}

fn restrict_dir(dir: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        if let Err(e) = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700)) {
            tracing::warn!(dir = %dir.display(), error = %e, "could not restrict the data directory to its owner");
        }
    }
    #[cfg(not(unix))]
    let _ = dir;
}
