//! Service configuration: one typed struct, filled from flags and environment by [`ServeArgs`].

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Command-line flags and environment variables of `eyekey serve`.
///
/// Secrets (`EYEKEY_OPERATOR_TOKEN`, `EYEKEY_MASTER_KEY`) are best passed through the environment; when
/// absent they are read from, or generated into, `operator-token` and `master.key` in the data directory
/// (mode 0600). Their values are never logged.
#[derive(clap::Args, Clone)]
pub struct ServeArgs {
    /// Address and port to listen on.
    #[arg(long, env = "EYEKEY_BIND", default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,
    /// TLS certificate chain (PEM); with `--tls-key`, the service speaks only HTTPS.
    #[arg(long, env = "EYEKEY_TLS_CERT", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// TLS private key (PEM: PKCS#8, PKCS#1 or SEC1).
    #[arg(long, env = "EYEKEY_TLS_KEY", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Serve plain HTTP on an address other than loopback (tokens and frames would cross the network in
    /// clear; only behind a TLS-terminating proxy on the same host).
    #[arg(long, env = "EYEKEY_INSECURE_HTTP")]
    pub insecure_http: bool,
    /// Time a client has to send a request's headers (and to finish a TLS handshake), seconds.
    #[arg(long, env = "EYEKEY_HEADER_TIMEOUT_SECS", default_value_t = 10)]
    pub header_timeout_secs: u64,
    /// Time a kept-alive connection may sit idle between requests before it is closed, seconds.
    #[arg(long, env = "EYEKEY_IDLE_TIMEOUT_SECS", default_value_t = 60)]
    pub idle_timeout_secs: u64,
    /// Connections open at once; beyond it new connections are closed as soon as they are accepted.
    #[arg(long, env = "EYEKEY_MAX_CONNECTIONS", default_value_t = 512)]
    pub max_connections: usize,
    /// Directory holding the database, uploaded documents, job outputs and generated secrets.
    #[arg(long, env = "EYEKEY_DATA_DIR", default_value = "./eyekey-data")]
    pub data_dir: PathBuf,
    /// The database: `sqlite://PATH` or `postgres://USER:PASSWORD@HOST:PORT/DB` (default: the SQLite file
    /// `eyekey.db` in the data directory). With PostgreSQL, documents and bundles are stored in the
    /// database too, so any number of `serve` and `worker` processes on any machines share one service.
    #[arg(long, env = "EYEKEY_DATABASE_URL", hide_env_values = true, value_parser = parse_location)]
    pub database_url: Option<crate::service::store::Location>,
    /// Operator bearer token (default: `<data-dir>/operator-token`, generated on first start).
    #[arg(long, env = "EYEKEY_OPERATOR_TOKEN", hide_env_values = true)]
    pub operator_token: Option<String>,
    /// Master key for profile encryption, 64 hex digits (default: `<data-dir>/master.key`, generated on
    /// first start).
    #[arg(long, env = "EYEKEY_MASTER_KEY", hide_env_values = true)]
    pub master_key: Option<String>,
    /// Jobs solved at once. Each job already spreads over every core (rayon), so 1 is usually right.
    #[arg(long, env = "EYEKEY_WORKERS", default_value_t = 1)]
    pub workers: usize,
    /// Largest accepted document upload, bytes.
    #[arg(long, env = "EYEKEY_MAX_DOCUMENT_BYTES", default_value_t = 20 * 1024 * 1024)]
    pub max_document_bytes: usize,
    /// Largest accepted document, pixels (width × height), checked before decoding.
    #[arg(long, env = "EYEKEY_MAX_DOCUMENT_PIXELS", default_value_t = 16 * 1024 * 1024)]
    pub max_document_pixels: u64,
    /// Largest accepted JSON request body, bytes.
    #[arg(long, env = "EYEKEY_MAX_BODY_BYTES", default_value_t = 1024 * 1024)]
    pub max_body_bytes: usize,
    /// Time a request may take until its response starts, seconds.
    #[arg(long, env = "EYEKEY_REQUEST_TIMEOUT_SECS", default_value_t = 30)]
    pub request_timeout_secs: u64,
    /// Lease a worker holds on a running job, seconds; renewed by a heartbeat every third of it.
    #[arg(long, env = "EYEKEY_LEASE_SECS", default_value_t = 30)]
    pub lease_secs: u64,
    /// Attempts a job gets before it fails (a crashed or timed-out attempt counts).
    #[arg(long, env = "EYEKEY_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// On shutdown, how long running jobs get to stop and be re-queued, seconds.
    #[arg(long, env = "EYEKEY_SHUTDOWN_GRACE_SECS", default_value_t = 20)]
    pub shutdown_grace_secs: u64,
    /// Memory bound of the transport-operator cache shared by all jobs, MiB (0 disables it).
    #[arg(long, env = "EYEKEY_TRANSPORT_CACHE_MB", default_value_t = 512)]
    pub transport_cache_mb: usize,
    /// Largest estimated peak memory of one job, MiB; jobs (and displays on which even the cheapest job) over
    /// it are refused before they start (default: half the machine's memory).
    #[arg(long, env = "EYEKEY_MAX_JOB_MEMORY_MB")]
    pub max_job_memory_mb: Option<u64>,
    /// Longest estimated run of one job on a 2-core machine, seconds; longer jobs (and displays on which even
    /// the cheapest job would take longer) are refused before they start.
    #[arg(long, env = "EYEKEY_MAX_JOB_SECONDS", default_value_t = 1800)]
    pub max_job_seconds: u64,
    /// Free space the data directory must keep, MiB: below it `/readyz` reports not ready.
    #[arg(long, env = "EYEKEY_MIN_FREE_MB", default_value_t = 256)]
    pub min_free_mb: u64,
    /// Days after which documents, jobs and their bundles are deleted (checked hourly); 0 keeps them until
    /// deleted by hand. Profiles never expire.
    #[arg(long, env = "EYEKEY_RETENTION_DAYS", default_value_t = 30, value_parser = clap::value_parser!(u32).range(0..=36500))]
    pub retention_days: u32,
}

/// Command-line flags and environment variables of `eyekey worker`: job workers with no API, on a
/// PostgreSQL database shared with `eyekey serve` processes.
#[derive(clap::Args, Clone)]
pub struct WorkerArgs {
    /// The database, `postgres://USER:PASSWORD@HOST:PORT/DB`, the same as the API processes'.
    #[arg(long, env = "EYEKEY_DATABASE_URL", hide_env_values = true, value_parser = parse_location)]
    pub database_url: crate::service::store::Location,
    /// Directory for this process's lock and, unless given by `EYEKEY_MASTER_KEY`, the master key file.
    #[arg(long, env = "EYEKEY_DATA_DIR", default_value = "./eyekey-worker")]
    pub data_dir: PathBuf,
    /// Master key, 64 hex digits: the one every eyekey process of this database shares (default:
    /// `<data-dir>/master.key`).
    #[arg(long, env = "EYEKEY_MASTER_KEY", hide_env_values = true)]
    pub master_key: Option<String>,
    /// Jobs solved at once by this process. Each job already spreads over every core (rayon), so 1 is
    /// usually right; run one worker process per machine.
    #[arg(long, env = "EYEKEY_WORKERS", default_value_t = 1)]
    pub workers: usize,
    /// Lease a worker holds on a running job, seconds; renewed by a heartbeat every third of it.
    #[arg(long, env = "EYEKEY_LEASE_SECS", default_value_t = 30)]
    pub lease_secs: u64,
    /// On shutdown, how long running jobs get to stop and be re-queued, seconds.
    #[arg(long, env = "EYEKEY_SHUTDOWN_GRACE_SECS", default_value_t = 20)]
    pub shutdown_grace_secs: u64,
    /// Memory bound of the transport-operator cache shared by this process's jobs, MiB (0 disables it).
    #[arg(long, env = "EYEKEY_TRANSPORT_CACHE_MB", default_value_t = 512)]
    pub transport_cache_mb: usize,
}

impl From<WorkerArgs> for Config {
    fn from(a: WorkerArgs) -> Self {
        let mut config = Config::new(a.data_dir);
        config.database = Some(a.database_url);
        config.master_key_hex = a.master_key.filter(|k| !k.is_empty());
        config.workers = a.workers;
        config.queue.lease = Duration::from_secs(a.lease_secs.max(1));
        config.queue.shutdown_grace = Duration::from_secs(a.shutdown_grace_secs);
        config.transport_cache_bytes = a.transport_cache_mb.saturating_mul(1 << 20);
        config
    }
}

/// Everything the service needs to start. Its `Debug` hides the secrets.
#[derive(Clone)]
pub struct Config {
    /// Listen address; port 0 picks a free port (see `Application::port`).
    pub bind: SocketAddr,
    /// TLS certificate chain and key (PEM files); `None` serves plain HTTP.
    pub tls: Option<(PathBuf, PathBuf)>,
    /// Allow plain HTTP on a non-loopback address.
    pub insecure_http: bool,
    /// Data directory.
    pub data_dir: PathBuf,
    /// The database; `None` is `<data_dir>/eyekey.db` (SQLite).
    pub database: Option<crate::service::store::Location>,
    /// Operator token; `None` reads or generates `<data_dir>/operator-token`.
    pub operator_token: Option<String>,
    /// Master key as 64 hex digits; `None` reads or generates `<data_dir>/master.key`.
    pub master_key_hex: Option<String>,
    /// Worker tasks (0 = none: jobs wait until a worker step is run by hand, as the tests do).
    pub workers: usize,
    /// Request and upload limits.
    pub limits: Limits,
    /// Queue behaviour.
    pub queue: QueueConfig,
    /// Memory bound of the process-wide transport-operator cache, bytes.
    pub transport_cache_bytes: usize,
    /// Age after which documents, jobs and bundles are deleted; `None` keeps them.
    pub retention: Option<Duration>,
    /// Largest estimated peak memory of one job, bytes.
    pub max_job_memory_bytes: u64,
    /// Longest estimated run of one job, seconds.
    pub max_job_seconds: f64,
    /// Free space below which the service is not ready, bytes.
    pub min_free_bytes: u64,
}

/// Request and upload limits.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest document upload, bytes.
    pub max_document_bytes: usize,
    /// Largest document, pixels.
    pub max_document_pixels: u64,
    /// Largest JSON body, bytes.
    pub max_body_bytes: usize,
    /// Time until a response starts.
    pub request_timeout: Duration,
    /// Time a client has from connecting to sending its request headers (a TLS handshake included).
    pub header_read_timeout: Duration,
    /// Time a connection may sit idle between requests.
    pub idle_timeout: Duration,
    /// Connections open at once.
    pub max_connections: usize,
}

/// Durable-queue behaviour.
#[derive(Clone, Debug)]
pub struct QueueConfig {
    /// Lease a worker holds on a claimed job.
    pub lease: Duration,
    /// Attempts before a job fails.
    pub max_attempts: u32,
    /// How often an idle worker looks for work it was not told about (expired leases).
    pub poll_interval: Duration,
    /// How long running jobs get to stop on shutdown.
    pub shutdown_grace: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_document_bytes: 20 * 1024 * 1024,
            max_document_pixels: 16 * 1024 * 1024,
            max_body_bytes: 1024 * 1024,
            request_timeout: Duration::from_secs(30),
            header_read_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 512,
        }
    }
}

impl Default for QueueConfig {
    fn default() -> Self {
        Self {
            lease: Duration::from_secs(30),
            max_attempts: 3,
            poll_interval: Duration::from_millis(500),
            shutdown_grace: Duration::from_secs(20),
        }
    }
}

impl Config {
    /// Defaults for everything but the data directory: port 8080 on loopback, one worker, generated secrets.
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 8080)),
            tls: None,
            insecure_http: false,
            data_dir: data_dir.into(),
            database: None,
            operator_token: None,
            master_key_hex: None,
            workers: 1,
            limits: Limits::default(),
            queue: QueueConfig::default(),
            transport_cache_bytes: 512 << 20,
            retention: Some(Duration::from_secs(30 * 86_400)),
            max_job_memory_bytes: default_job_memory_bytes(),
            max_job_seconds: 1800.0,
            min_free_bytes: 256 << 20,
        }
    }

    /// The path of the SQLite database in the data directory (the default database).
    pub fn database_path(&self) -> PathBuf {
        self.data_dir.join("eyekey.db")
    }

    /// Where the database is.
    pub fn database_location(&self) -> crate::service::store::Location {
        self.database
            .clone()
            .unwrap_or_else(|| crate::service::store::Location::Sqlite(self.database_path()))
    }
}

impl From<ServeArgs> for Config {
    fn from(a: ServeArgs) -> Self {
        Self {
            bind: a.bind,
            tls: a.tls_cert.zip(a.tls_key),
            insecure_http: a.insecure_http,
            data_dir: a.data_dir,
            database: a.database_url,
            operator_token: a.operator_token.filter(|t| !t.is_empty()),
            master_key_hex: a.master_key.filter(|k| !k.is_empty()),
            workers: a.workers,
            limits: Limits {
                max_document_bytes: a.max_document_bytes,
                max_document_pixels: a.max_document_pixels,
                max_body_bytes: a.max_body_bytes,
                request_timeout: Duration::from_secs(a.request_timeout_secs.max(1)),
                header_read_timeout: Duration::from_secs(a.header_timeout_secs.max(1)),
                idle_timeout: Duration::from_secs(a.idle_timeout_secs.max(1)),
                max_connections: a.max_connections.max(1),
            },
            queue: QueueConfig {
                lease: Duration::from_secs(a.lease_secs.max(1)),
                max_attempts: a.max_attempts.max(1),
                shutdown_grace: Duration::from_secs(a.shutdown_grace_secs),
                ..QueueConfig::default()
            },
            transport_cache_bytes: a.transport_cache_mb.saturating_mul(1 << 20),
            retention: (a.retention_days > 0).then(|| Duration::from_secs(u64::from(a.retention_days) * 86_400)),
            max_job_memory_bytes: a
                .max_job_memory_mb
                .map_or_else(default_job_memory_bytes, |mb| mb.saturating_mul(1 << 20)),
            max_job_seconds: a.max_job_seconds.max(1) as f64,
            min_free_bytes: a.min_free_mb.saturating_mul(1 << 20),
        }
    }
}

fn parse_location(text: &str) -> Result<crate::service::store::Location, String> {
    crate::service::store::Location::parse(text)
}

/// Half of the machine's memory (`MemTotal` of `/proc/meminfo`), or 4 GiB where it cannot be read.
pub fn default_job_memory_bytes() -> u64 {
    let total_kb = std::fs::read_to_string("/proc/meminfo").ok().and_then(|text| {
        text.lines()
            .find_map(|l| l.strip_prefix("MemTotal:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
    });
    total_kb.map_or(4 << 30, |kb| kb * 1024 / 2)
}

/// Stands in for a secret in `Debug` output.
fn redacted(secret: &Option<String>) -> &'static str {
    if secret.is_some() {
        "Some(<redacted>)"
    } else {
        "None"
    }
}

impl std::fmt::Debug for Config {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Config")
            .field("bind", &self.bind)
            .field("tls", &self.tls)
            .field("insecure_http", &self.insecure_http)
            .field("data_dir", &self.data_dir)
            .field("database", &self.database)
            .field("operator_token", &redacted(&self.operator_token))
            .field("master_key_hex", &redacted(&self.master_key_hex))
            .field("workers", &self.workers)
            .field("limits", &self.limits)
            .field("queue", &self.queue)
            .field("transport_cache_bytes", &self.transport_cache_bytes)
            .field("retention", &self.retention)
            .field("max_job_memory_bytes", &self.max_job_memory_bytes)
            .field("max_job_seconds", &self.max_job_seconds)
            .field("min_free_bytes", &self.min_free_bytes)
            .finish()
    }
}

impl std::fmt::Debug for WorkerArgs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Debug::fmt(&Config::from(self.clone()), f)
    }
}

impl std::fmt::Debug for ServeArgs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Debug::fmt(&Config::from(self.clone()), f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn debug_output_never_shows_the_secrets() {
        let mut c = Config::new("/tmp/x");
        c.operator_token = Some("op-secret".into());
        c.master_key_hex = Some("ab".repeat(32));
        let text = format!("{c:?}");
        assert!(
            !text.contains("op-secret") && !text.contains(&"ab".repeat(32)),
            "{text}"
        );
        assert!(text.contains("<redacted>"));
    }
}
