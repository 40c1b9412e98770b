//! The client's configuration: the command line of `eyekey display-client` and the [`ClientConfig`] a sync
//! runs with.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::error::{error_chain, io_err, ClientError};
use super::CURRENT_DIR;
use eyekey_core::physics::profile::VisionProfile;

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
    /// A CA certificate (PEM) to trust for the server's TLS certificate, besides the system's roots (which
    /// also honour `SSL_CERT_FILE`).
    #[arg(long, env = "EYEKEY_CA")]
    pub ca: Option<PathBuf>,
    /// Allow a plain `http://` server that is not on this machine (the token and the frames would cross the
    /// network in clear).
    #[arg(long)]
    pub insecure_http: bool,
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
            .field("ca", &self.ca)
            .field("insecure_http", &self.insecure_http)
            .finish()
    }
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
    pub(super) http: reqwest::Client,
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
    /// A configuration with default timings (poll every 5 s, backoff 1 s doubling up to 60 s), trusting the
    /// system's roots, refusing plain HTTP to anything but this machine.
    pub fn new(server: &str, token: &str, out_dir: impl Into<PathBuf>) -> Result<Self, ClientError> {
        Self::with_transport(server, token, out_dir, None, false)
    }

    /// [`ClientConfig::new`] that also trusts the CA certificate in `ca` (PEM), and with `insecure_http`
    /// allows plain HTTP to another machine.
    pub fn with_transport(
        server: &str,
        token: &str,
        out_dir: impl Into<PathBuf>,
        ca: Option<&Path>,
        insecure_http: bool,
    ) -> Result<Self, ClientError> {
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
        if url.scheme() == "http" && !insecure_http && !is_loopback(&url) {
            return Err(ClientError::Config(format!(
                "--server {server:?} is plain http to another machine: the token and the frames would cross the \
                 network in clear. Use https, or pass --insecure-http"
            )));
        }
        let mut builder = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(10))
            .read_timeout(READ_IDLE_TIMEOUT)
            .https_only(url.scheme() == "https")
            .user_agent(concat!("eyekey-display-client/", env!("CARGO_PKG_VERSION")));
        if let Some(path) = ca {
            let pem = std::fs::read(path).map_err(io_err("read the --ca certificate", path))?;
            let certs = reqwest::Certificate::from_pem_bundle(&pem)
                .map_err(|e| ClientError::Config(format!("--ca {}: {}", path.display(), error_chain(&e))))?;
            if certs.is_empty() {
                return Err(ClientError::Config(format!(
                    "--ca {} holds no PEM certificate",
                    path.display()
                )));
            }
            for cert in certs {
                builder = builder.add_root_certificate(cert);
            }
        }
        let http = builder
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
        let mut cfg = Self::with_transport(&a.server, &a.token, &a.out, a.ca.as_deref(), a.insecure_http)?;
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

    pub(super) fn url(&self, path: &str) -> String {
        format!("{}{path}", self.server)
    }

    /// `DIR/current`.
    pub fn current_dir(&self) -> PathBuf {
        self.out_dir.join(CURRENT_DIR)
    }
}

/// True when the URL's host is this machine: `localhost`, 127.0.0.0/8 or ::1.
fn is_loopback(url: &reqwest::Url) -> bool {
    let Some(host) = url.host_str() else { return false };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost") || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn plain_http_is_only_for_this_machine_unless_allowed() {
        for local in ["http://127.0.0.1:8080", "http://localhost:1", "http://[::1]:8080"] {
            assert!(ClientConfig::new(local, "t", "/tmp/x").is_ok(), "{local}");
        }
        let err = ClientConfig::new("http://10.0.0.7:8080", "t", "/tmp/x").unwrap_err();
        assert!(err.to_string().contains("--insecure-http"), "{err}");
        assert!(ClientConfig::with_transport("http://10.0.0.7:8080", "t", "/tmp/x", None, true).is_ok());
        assert!(ClientConfig::new("https://10.0.0.7:8443", "t", "/tmp/x").is_ok());
        let missing =
            ClientConfig::with_transport("https://x", "t", "/tmp/x", Some(Path::new("/nonexistent.pem")), false);
        assert!(missing.is_err());
    }
}
