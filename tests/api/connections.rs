//! Every connection has a deadline: one that sends no request's headers in time (silent, not speaking HTTP,
//! trickling, or stuck in its TLS handshake) is closed within the header timeout, one idle between requests
//! within the idle timeout, a response still streaming is not cut, and beyond `max_connections` new connections
//! are closed at once. Real sockets, on plain HTTP and on TLS.

use std::io::{Read as _, Write as _};
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};

use reqwest::StatusCode;

use crate::helpers::{spawn_app_in, spawn_app_with, TestApp};
use crate::transport::certificates;

const HEADER: Duration = Duration::from_secs(1);
const IDLE: Duration = Duration::from_secs(2);

fn limits(c: &mut eyekey::service::Config) {
    c.limits.header_read_timeout = HEADER;
    c.limits.idle_timeout = IDLE;
}

/// A raw connection to `app`'s port that has sent `bytes`.
fn open(app: &TestApp, bytes: &[u8]) -> (TcpStream, Instant) {
    let host = app.address.split("://").nth(1).unwrap().to_string();
    let mut tcp = TcpStream::connect(host).unwrap();
    let started = Instant::now();
    tcp.write_all(bytes).unwrap();
    (tcp, started)
}

/// When the server closed `tcp`, counted from `started` (reading and dropping whatever it sends), or `None` if it
/// is still open `wait` after `started`.
fn closed_after(tcp: &mut TcpStream, started: Instant, wait: Duration) -> Option<Duration> {
    let mut buf = [0u8; 4096];
    loop {
        let left = wait.checked_sub(started.elapsed())?;
        tcp.set_read_timeout(Some(left.max(Duration::from_millis(1)))).unwrap();
        match tcp.read(&mut buf) {
            Ok(0) => return Some(started.elapsed()),
            Ok(_) => continue,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                return None;
            }
            Err(_) => return Some(started.elapsed()),
        }
    }
}

/// Opens every one of `openings` on `app` at once and returns when the server closed each (`None`: open after
/// `wait`).
async fn closing_times(app: &TestApp, openings: &[&[u8]], wait: Duration) -> Vec<Option<Duration>> {
    let opened: Vec<(TcpStream, Instant)> = openings.iter().map(|b| open(app, b)).collect();
    tokio::task::spawn_blocking(move || {
        opened
            .into_iter()
            .map(|(mut tcp, started)| closed_after(&mut tcp, started, wait))
            .collect()
    })
    .await
    .unwrap()
}

/// Opens every one of `openings` at once and checks the server closed each within the header timeout (and some
/// slack for a loaded machine); returns when it closed each.
async fn closed_within_the_header_timeout(app: &TestApp, openings: &[&[u8]]) -> Vec<Option<Duration>> {
    let times = closing_times(app, openings, Duration::from_secs(8)).await;
    for (kind, took) in openings.iter().zip(&times) {
        let took = took.unwrap_or_else(|| panic!("{kind:?}: still open after 8 s"));
        assert!(
            took < HEADER + Duration::from_secs(2),
            "{kind:?}: closed after {took:?}"
        );
    }
    times
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plain_connections_that_send_no_request_are_closed_within_the_header_timeout_and_idle_ones_after_the_idle_timeout(
) {
    let app = spawn_app_with(limits).await;
    // Silent, three bytes that are not HTTP, half a request line, and headers without their end: ten of each.
    let kinds: [&[u8]; 4] = [
        b"",
        b"\x16\x03\x01",
        b"GET /hea",
        b"GET /healthz HTTP/1.1\r\nHost: x\r\n",
    ];
    let openings: Vec<&[u8]> = kinds.iter().flat_map(|k| std::iter::repeat_n(*k, 10)).collect();
    let times = closed_within_the_header_timeout(&app, &openings).await;
    // A silent connection is closed by its deadline, not at once.
    assert!(times[0].unwrap() >= HEADER - Duration::from_millis(100), "{times:?}");

    // A kept-alive connection that asked once is answered, then closed after the idle timeout (longer than the
    // header timeout: the deadline between requests is the idle one).
    let (mut tcp, _) = open(&app, b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n");
    let answered = Instant::now();
    let took = tokio::task::spawn_blocking(move || closed_after(&mut tcp, answered, Duration::from_secs(10)))
        .await
        .unwrap()
        .expect("closed within 10 s");
    assert!(
        took >= IDLE - Duration::from_millis(300) && took < IDLE + Duration::from_secs(2),
        "idle connection closed after {took:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_connections_that_stall_in_the_handshake_or_send_no_request_are_closed_within_the_header_timeout() {
    let pem = tempfile::tempdir().unwrap();
    let (ca, cert, key) = certificates(pem.path());
    let data = tempfile::tempdir().unwrap();
    let app = spawn_app_in(data.path(), |c| {
        c.tls = Some((cert.clone(), key.clone()));
        limits(c);
    })
    .await;
    // Three bytes of a TLS handshake, and silence: ten of each.
    let openings: Vec<&[u8]> = [b"\x16\x03\x01" as &[u8], b""]
        .iter()
        .flat_map(|k| std::iter::repeat_n(*k, 10))
        .collect();
    closed_within_the_header_timeout(&app, &openings).await;

    // A finished handshake and no request: closed within the header timeout of the accept. One request and
    // then nothing: closed after the idle timeout.
    use rustls_pki_types::pem::PemObject as _;
    let mut roots = tokio_rustls::rustls::RootCertStore::empty();
    roots
        .add(rustls_pki_types::CertificateDer::from_pem_file(&ca).unwrap())
        .unwrap();
    let config = tokio_rustls::rustls::ClientConfig::builder_with_provider(Arc::new(
        tokio_rustls::rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(config));
    let host = app.address.trim_start_matches("https://").to_string();
    for request in [None, Some(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n" as &[u8])] {
        use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
        let tcp = tokio::net::TcpStream::connect(&host).await.unwrap();
        let started = Instant::now();
        let name = rustls_pki_types::ServerName::try_from("localhost").unwrap();
        let mut tls = connector.connect(name, tcp).await.expect("the handshake completes");
        if let Some(r) = request {
            tls.write_all(r).await.unwrap();
        }
        let answered = Instant::now();
        let mut buf = Vec::new();
        let read = tokio::time::timeout(Duration::from_secs(10), tls.read_to_end(&mut buf)).await;
        assert!(read.is_ok(), "{request:?}: still open after 10 s");
        match request {
            None => {
                let took = started.elapsed();
                assert!(took < HEADER + Duration::from_secs(2), "closed after {took:?}");
            }
            Some(_) => {
                assert!(String::from_utf8_lossy(&buf).starts_with("HTTP/1.1 200"));
                let took = answered.elapsed();
                assert!(
                    took >= IDLE - Duration::from_millis(300) && took < IDLE + Duration::from_secs(2),
                    "idle TLS connection closed after {took:?}"
                );
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn beyond_max_connections_a_new_connection_is_closed_at_once_and_a_streaming_response_outlives_the_idle_timeout()
{
    let app = spawn_app_with(|c| {
        limits(c);
        c.limits.header_read_timeout = Duration::from_secs(3);
        c.limits.max_connections = 4;
    })
    .await;
    // The harness's own kept-alive connections close after the idle timeout.
    tokio::time::sleep(IDLE + Duration::from_millis(500)).await;
    let held: Vec<(TcpStream, Instant)> = (0..4).map(|_| open(&app, b"")).collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (mut extra, started) = open(&app, b"");
    let refused = tokio::task::spawn_blocking(move || closed_after(&mut extra, started, Duration::from_secs(2)))
        .await
        .unwrap();
    assert!(
        refused.is_some_and(|t| t < Duration::from_millis(1000)),
        "the fifth connection: {refused:?}"
    );
    // Once the four are closed (header timeout), the server takes connections again.
    let closed = tokio::task::spawn_blocking(move || {
        held.into_iter()
            .map(|(mut tcp, started)| closed_after(&mut tcp, started, Duration::from_secs(8)))
            .collect::<Vec<_>>()
    })
    .await
    .unwrap();
    assert!(closed.iter().all(Option::is_some), "{closed:?}");
    let r = reqwest::Client::new().get(app.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);

    // A display's event stream sends nothing for 15 s at a time; it stays open past the idle timeout.
    let f = app.fixtures().await;
    let mut events = reqwest::Client::new()
        .get(app.url("/v1/frames/events"))
        .bearer_auth(&f.display_token)
        .send()
        .await
        .unwrap();
    assert_eq!(events.status(), StatusCode::OK);
    let waited = tokio::time::timeout(IDLE * 2, events.chunk()).await;
    assert!(
        !matches!(waited, Ok(Ok(None)) | Ok(Err(_))),
        "the event stream ended: {waited:?}"
    );
}
