//! The HTTP(S) listener: accepts connections, runs TLS when configured, and serves the router over HTTP/1.1
//! and HTTP/2 with a bound on how long a client may take to send its request headers.
//!
//! Written on hyper directly (axum's own `serve` has no header timeout and no TLS): a connection that has not
//! sent a request's headers within the header timeout of its accept (silent, trickling, not speaking HTTP, or
//! stuck in its TLS handshake) is dropped, as is one idle between requests past the idle timeout, and at most
//! `max_connections` are open at once, so slow clients cannot hold the server's sockets (the slowloris pattern).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use axum::Router;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};

/// A TLS server configuration from a PEM certificate chain and a PEM private key (PKCS#8, PKCS#1 or SEC1).
pub fn tls_acceptor(cert: &Path, key: &Path) -> anyhow::Result<tokio_rustls::TlsAcceptor> {
    use rustls_pki_types::pem::PemObject as _;
    use rustls_pki_types::{CertificateDer, PrivateKeyDer};
    let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(cert)
        .with_context(|| format!("reading the TLS certificate {}", cert.display()))?
        .collect::<Result<_, _>>()
        .with_context(|| format!("parsing the TLS certificate {}", cert.display()))?;
    anyhow::ensure!(!chain.is_empty(), "{} holds no PEM certificate", cert.display());
    let key = PrivateKeyDer::from_pem_file(key).with_context(|| format!("reading the TLS key {}", key.display()))?;
    let provider = Arc::new(tokio_rustls::rustls::crypto::ring::default_provider());
    let mut config = tokio_rustls::rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .context("the TLS certificate and key do not fit together")?;
    config.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(tokio_rustls::TlsAcceptor::from(Arc::new(config)))
}

/// What a connection may hold and for how long.
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    /// From the accept to a request's headers being in, the TLS handshake included.
    pub header_timeout: Duration,
    /// Between requests on a kept-alive connection, with none in flight.
    pub idle_timeout: Duration,
    /// Connections open at once; beyond it new ones are closed as soon as they are accepted.
    pub max_connections: usize,
}

/// Serves `router` on `listener` until `stop` turns true, then lets open connections finish for up to
/// `grace`.
///
/// Every connection has a deadline while no request is in flight: `header_timeout` from the accept until its
/// first request's headers are in (a TLS handshake, silence or bytes that never form a request all count), then
/// `idle_timeout` from the end of each response until the next request's headers. A response still streaming
/// holds its connection open however long it takes.
pub async fn serve(
    listener: TcpListener,
    router: Router,
    tls: Option<tokio_rustls::TlsAcceptor>,
    limits: ConnectionLimits,
    mut stop: watch::Receiver<bool>,
    grace: Duration,
) -> std::io::Result<()> {
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    let mut builder = Builder::new(TokioExecutor::new());
    // hyper's own HTTP/1 timer runs from when it waits for a request's head: for the first request the deadline
    // below (from the accept) comes first; between requests it is the idle timeout.
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.idle_timeout.max(limits.header_timeout));
    builder.http2().timer(TokioTimer::new());
    let builder = Arc::new(builder);
    let permits = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let mut refusing = false;
    loop {
        let (tcp, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(c) => c,
                Err(e) => {
                    // Out of file descriptors and the like: wait a moment rather than spin.
                    tracing::warn!(error = %e, "accepting a connection failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = super::state::stopped(&mut stop) => break,
        };
        let Ok(permit) = permits.clone().try_acquire_owned() else {
            // Logged once per spell at the cap, not once per connection of a flood.
            if !refusing {
                tracing::warn!(%peer, max = limits.max_connections, "at the connection cap; closing new connections");
                refusing = true;
            }
            drop(tcp);
            continue;
        };
        if refusing {
            tracing::info!("below the connection cap again");
            refusing = false;
        }
        // A streamed body goes out in several writes; Nagle's algorithm with the client's delayed ACK would
        // hold each response's last segment for ~40 ms.
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!(error = %e, "could not set TCP_NODELAY");
        }
        let accepted = Instant::now();
        let activity = Activity::new(accepted);
        let service = Tracked {
            inner: TowerToHyperService::new(router.clone()),
            activity: activity.clone(),
        };
        let builder = builder.clone();
        let watcher = graceful.watcher();
        let tls = tls.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let result = match tls {
                None => {
                    let conn = builder.serve_connection(TokioIo::new(tcp), service).into_owned();
                    activity.bound(watcher.watch(conn), limits, peer).await
                }
                Some(acceptor) => {
                    let deadline = accepted + limits.header_timeout;
                    match tokio::time::timeout_at(deadline.into(), acceptor.accept(tcp)).await {
                        Ok(Ok(stream)) => {
                            let conn = builder.serve_connection(TokioIo::new(stream), service).into_owned();
                            activity.bound(watcher.watch(conn), limits, peer).await
                        }
                        Ok(Err(e)) => {
                            tracing::debug!(%peer, error = %e, "TLS handshake failed");
                            return;
                        }
                        Err(_) => {
                            tracing::debug!(%peer, "TLS handshake timed out");
                            return;
                        }
                    }
                }
            };
            if let Err(e) = result {
                tracing::debug!(%peer, error = %e, "connection ended with an error");
            }
        });
    }
    drop(listener);
    if tokio::time::timeout(grace, graceful.shutdown()).await.is_err() {
        tracing::warn!(?grace, "connections still open after the grace period; closing them");
    }
    Ok(())
}

/// What a connection is doing: requests in flight (until their response bodies are done), requests begun, and
/// when the count last changed.
#[derive(Clone, Copy)]
struct Load {
    in_flight: usize,
    begun: u64,
    since: Instant,
}

/// A connection's [`Load`], watched by its deadline.
#[derive(Clone)]
struct Activity(Arc<watch::Sender<Load>>);

impl Activity {
    fn new(now: Instant) -> Self {
        Self(Arc::new(watch::Sender::new(Load {
            in_flight: 0,
            begun: 0,
            since: now,
        })))
    }

    /// A request's headers are in: it counts until the returned guard (held by its response body) drops.
    fn begin(&self) -> InFlight {
        self.0.send_modify(|l| {
            l.in_flight += 1;
            l.begun += 1;
            l.since = Instant::now();
        });
        InFlight(self.clone())
    }

    /// Runs `conn` until it ends or stays without a request in flight past its deadline (then drops it).
    async fn bound<F, E>(&self, conn: F, limits: ConnectionLimits, peer: std::net::SocketAddr) -> Result<(), E>
    where
        F: std::future::Future<Output = Result<(), E>>,
    {
        tokio::pin!(conn);
        let mut load = self.0.subscribe();
        loop {
            let now = *load.borrow_and_update();
            let idle = async {
                if now.in_flight > 0 {
                    std::future::pending::<()>().await;
                }
                let limit = if now.begun == 0 {
                    limits.header_timeout
                } else {
                    limits.idle_timeout
                };
                tokio::time::sleep_until((now.since + limit).into()).await;
            };
            tokio::select! {
                result = &mut conn => return result,
                _ = load.changed() => continue,
                () = idle => {
                    tracing::debug!(%peer, requests = now.begun, "closing a connection that sent no request in time");
                    return Ok(());
                }
            }
        }
    }
}

/// One request in flight on a connection.
struct InFlight(Activity);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0 .0.send_modify(|l| {
            l.in_flight -= 1;
            l.since = Instant::now();
        });
    }
}

/// The router as hyper calls it, each request counted in its connection's [`Activity`] until its response body
/// is done or dropped.
#[derive(Clone)]
struct Tracked {
    inner: TowerToHyperService<Router>,
    activity: Activity,
}

impl hyper::service::Service<hyper::Request<hyper::body::Incoming>> for Tracked {
    type Response = hyper::Response<axum::body::Body>;
    type Error = std::convert::Infallible;
    type Future = std::pin::Pin<Box<dyn std::future::Future<Output = Result<Self::Response, Self::Error>> + Send>>;

    fn call(&self, request: hyper::Request<hyper::body::Incoming>) -> Self::Future {
        let guard = self.activity.begin();
        let response = self.inner.call(request);
        Box::pin(async move {
            let response = response.await?;
            Ok(response.map(|body| {
                axum::body::Body::new(http_body_util::BodyExt::map_frame(body, move |frame| {
                    let _ = &guard;
                    frame
                }))
            }))
        })
    }
}
