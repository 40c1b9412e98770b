//! The service's transport and process guards: TLS, plain HTTP only on loopback, slow and oversize clients,
//! one server per data directory, the master key, readiness, and a full disk.

use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use reqwest::StatusCode;

use crate::helpers::{document_png, expect_json, spawn_app_in, spawn_app_with, test_config, OPERATOR_TOKEN};
use eyekey::client::{sync_once, ClientConfig, SyncOutcome};
use eyekey::service::Application;

/// The error `Application::build` gives for `config`, which must be refused.
async fn refusal(config: eyekey::service::Config) -> String {
    let err = Application::build(config).await.err().expect("refused");
    format!("{err:#}")
}

/// A CA and a certificate for localhost and 127.0.0.1 signed by it, written as PEM files into `dir`:
/// (CA certificate, server certificate, server key).
pub(crate) fn certificates(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    ca_params
        .distinguished_name
        .push(rcgen::DnType::CommonName, "eyekey test CA");
    let ca_key = rcgen::KeyPair::generate().unwrap();
    let ca = ca_params.self_signed(&ca_key).unwrap();
    let leaf_params = rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()]).unwrap();
    let leaf_key = rcgen::KeyPair::generate().unwrap();
    let leaf = leaf_params.signed_by(&leaf_key, &ca, &ca_key).unwrap();
    let paths = (dir.join("ca.pem"), dir.join("server.pem"), dir.join("server.key"));
    std::fs::write(&paths.0, ca.pem()).unwrap();
    std::fs::write(&paths.1, leaf.pem()).unwrap();
    std::fs::write(&paths.2, leaf_key.serialize_pem()).unwrap();
    (paths.0, paths.1, paths.2)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_tls_the_display_client_trusts_the_servers_ca_and_nothing_else_gets_in() {
    let pem = tempfile::tempdir().unwrap();
    let (ca, cert, key) = certificates(pem.path());
    let data = tempfile::tempdir().unwrap();
    let mut app = spawn_app_in(data.path(), |c| {
        c.tls = Some((cert.clone(), key.clone()));
        c.workers = 1;
    })
    .await;
    assert!(app.address.starts_with("https://"), "{}", app.address);

    // A client that trusts the CA talks to the service; one that does not is refused in the handshake.
    let ca_cert = reqwest::Certificate::from_pem(&std::fs::read(&ca).unwrap()).unwrap();
    let trusting = reqwest::Client::builder()
        .add_root_certificate(ca_cert)
        .build()
        .unwrap();
    let r = trusting.get(app.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert!(
        reqwest::Client::new().get(app.url("/healthz")).send().await.is_err(),
        "an unknown CA is refused"
    );
    let plain = app.url("/healthz").replacen("https://", "http://", 1);
    let r = reqwest::Client::new().get(&plain).send().await;
    assert!(
        r.is_err() || !r.unwrap().status().is_success(),
        "no plain HTTP on the TLS port"
    );

    // The display client, given the CA with --ca, installs a real bundle over TLS (the test's own requests
    // go through the trusting client too).
    app.client = trusting;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let job = app.wait_for_terminal(&id, Duration::from_secs(120)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let out = tempfile::tempdir().unwrap();
    let cfg = ClientConfig::with_transport(&app.address, &f.display_token, out.path(), Some(&ca), false).unwrap();
    assert!(matches!(sync_once(&cfg).await.unwrap(), SyncOutcome::Installed { .. }));
    let untrusting = ClientConfig::new(&app.address, &f.display_token, out.path()).unwrap();
    assert!(
        sync_once(&untrusting).await.is_err(),
        "without --ca the server's certificate is not trusted"
    );

    // The installed client trusts a CA named by SSL_CERT_FILE (the system roots' standard override) too.
    let client = |ssl_cert_file: Option<&Path>| {
        let out = tempfile::tempdir().unwrap();
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_eyekey"));
        command
            .args(["display-client", "--once", "--server", &app.address, "--out"])
            .arg(out.path())
            .env("EYEKEY_DISPLAY_TOKEN", &f.display_token)
            .env_remove("SSL_CERT_FILE")
            .env_remove("SSL_CERT_DIR");
        if let Some(file) = ssl_cert_file {
            command.env("SSL_CERT_FILE", file);
        }
        let run = command.output().unwrap();
        (
            run.status.success(),
            out.path().join("current").is_dir(),
            String::from_utf8_lossy(&run.stderr).into_owned(),
        )
    };
    let (ok, installed, log) = client(Some(&ca));
    assert!(ok && installed, "with SSL_CERT_FILE: {log}");
    let (ok, installed, _) = client(None);
    assert!(
        !ok && !installed,
        "with neither --ca nor SSL_CERT_FILE the certificate is refused"
    );
}

#[tokio::test]
async fn plain_http_is_served_only_on_loopback_unless_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(dir.path());
    config.bind = "0.0.0.0:0".parse().unwrap();
    let text = refusal(config.clone()).await;
    assert!(text.contains("--tls-cert"), "{text}");
    config.insecure_http = true;
    assert!(Application::build(config).await.is_ok(), "allowed when asked for");
}

/// Sends raw bytes to the server and returns what it answers until it closes the connection (or `wait`).
fn raw_exchange(address: &str, request: &[u8], pause_after: Option<Duration>, wait: Duration) -> (Vec<u8>, Duration) {
    let host = address.trim_start_matches("http://");
    let mut tcp = std::net::TcpStream::connect(host).unwrap();
    tcp.set_read_timeout(Some(wait)).unwrap();
    let started = Instant::now();
    tcp.write_all(request).unwrap();
    if let Some(p) = pause_after {
        std::thread::sleep(p);
    }
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tcp.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => {
                answer.extend_from_slice(&buf[..n]);
                if answer.windows(4).any(|w| w == b"\r\n\r\n") && pause_after.is_none() {
                    break;
                }
            }
        }
    }
    (answer, started.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_trickling_its_headers_is_cut_off_and_an_oversize_body_is_refused_at_once() {
    let app = spawn_app_with(|c| c.limits.header_read_timeout = Duration::from_secs(1)).await;
    let address = app.address.clone();
    // Half a request's headers, then silence: the server closes the connection after about a second.
    let (_, took) = tokio::task::spawn_blocking({
        let address = address.clone();
        move || {
            raw_exchange(
                &address,
                b"GET /healthz HTTP/1.1\r\nHost: x\r\n",
                None,
                Duration::from_secs(20),
            )
        }
    })
    .await
    .unwrap();
    assert!(took < Duration::from_secs(5), "held for {took:?}");

    // 100 GB announced: 413 at once, without waiting for a byte of the body.
    let request = format!(
        "POST /v1/documents HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {OPERATOR_TOKEN}\r\n\
         Content-Type: image/png\r\nContent-Length: 100000000000\r\n\r\n"
    );
    let (answer, took) =
        tokio::task::spawn_blocking(move || raw_exchange(&address, request.as_bytes(), None, Duration::from_secs(20)))
            .await
            .unwrap();
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(took < Duration::from_secs(2), "took {took:?}");
}

#[tokio::test]
async fn a_second_server_cannot_open_the_same_data_directory() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let text = refusal(test_config(dir.path())).await;
    assert!(text.contains("another eyekey server"), "{text}");
    app.stop().await;
    let again = spawn_app_in(dir.path(), |_| {}).await;
    again.stop().await;
}

#[tokio::test]
async fn a_missing_master_key_is_an_error_never_a_new_key_and_a_bad_one_names_its_file() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    app.enrol(&crate::helpers::myope()).await;
    app.stop().await;
    let key_file = dir.path().join("master.key");
    let key = std::fs::read(&key_file).unwrap();
    std::fs::remove_file(&key_file).unwrap();
    let text = refusal(test_config(dir.path())).await;
    assert!(
        text.contains("master.key is missing") && text.contains("backup"),
        "{text}"
    );
    assert!(!key_file.exists(), "no new key was written");
    std::fs::write(&key_file, "not a key").unwrap();
    let text = refusal(test_config(dir.path())).await;
    assert!(
        text.contains("master.key") && !text.contains("EYEKEY_MASTER_KEY"),
        "{text}"
    );
    std::fs::write(&key_file, key).unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    app.stop().await;
}

/// A tmpfs of `mib` MiB mounted at a new temporary directory, unmounted when dropped. The test that uses it
/// runs as root (as CI does) and fails, never skips, when it cannot mount.
struct Tmpfs {
    dir: tempfile::TempDir,
}

impl Tmpfs {
    fn mount(mib: u32) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let status = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={mib}m"), "tmpfs"])
            .arg(dir.path())
            .status()
            .expect("running mount");
        assert!(
            status.success(),
            "mounting a tmpfs needs root: run the tests as root, as .ci/run does"
        );
        Self { dir }
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount")
            .arg("-l")
            .arg(self.dir.path())
            .status();
    }
}

/// Fills the file system holding `dir` with one file, to the last byte it takes.
fn fill(dir: &Path) -> PathBuf {
    let path = dir.join("filler");
    let mut f = std::fs::File::create(&path).unwrap();
    let block = vec![0xA5u8; 64 * 1024];
    while f.write_all(&block).is_ok() {}
    for _ in 0..64 {
        let _ = f.write_all(&[0xA5u8; 1024]);
    }
    let _ = f.flush();
    path
}

/// A data directory that takes no new file (immutable, which binds root too) makes `/readyz` fail, naming the
/// cause; when it takes writes again the service is ready again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readiness_fails_while_the_data_directory_takes_no_write() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let app = spawn_app_in(&data, |_| {}).await;
    assert_eq!(app.op_get("/readyz").await.status(), StatusCode::OK);
    let chattr = |flag: &str| {
        let run = std::process::Command::new("chattr")
            .arg(flag)
            .arg(&data)
            .output()
            .expect("chattr (e2fsprogs)");
        assert!(
            run.status.success(),
            "chattr {flag}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
    };
    chattr("+i");
    let r = app.op_get("/readyz").await;
    let status = r.status();
    let body = r.text().await.unwrap();
    chattr("-i");
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    assert!(body.contains("not writable"), "{body}");
    assert_eq!(app.op_get("/readyz").await.status(), StatusCode::OK);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_answers_507_and_the_service_recovers_when_space_returns() {
    let disk = Tmpfs::mount(24);
    let data = disk.dir.path().join("data");
    let app = spawn_app_in(&data, |c| c.min_free_bytes = 1 << 20).await;
    let f = app.fixtures().await;
    assert_eq!(app.op_get("/readyz").await.status(), StatusCode::OK);
    let filler = fill(disk.dir.path());

    let upload = |png: Vec<u8>| {
        app.client
            .post(app.url("/v1/documents"))
            .bearer_auth(OPERATOR_TOKEN)
            .header("content-type", "image/png")
            .body(png)
            .send()
    };
    let r = upload(document_png(200, 200)).await.unwrap();
    let status = r.status();
    let body: serde_json::Value = r.json().await.unwrap();
    assert_eq!(status, StatusCode::INSUFFICIENT_STORAGE, "{body}");
    assert_eq!(body["error"]["code"], "insufficient_storage");
    assert!(body["error"]["message"].as_str().unwrap().contains("full"), "{body}");
    // Enrolment and job creation write to the database: they succeed into space it already holds, or answer
    // 507; never a 500.
    for r in [
        app.op_post(
            "/v1/profiles",
            &serde_json::json!({ "profile": crate::helpers::myope() }),
        )
        .await,
        app.op_post("/v1/jobs", &crate::helpers::job_body(&f)).await,
    ] {
        let status = r.status();
        assert!(
            status.is_success() || status == StatusCode::INSUFFICIENT_STORAGE,
            "{status}: {}",
            r.text().await.unwrap()
        );
    }
    let r = app.op_get("/readyz").await;
    assert_eq!(r.status(), StatusCode::SERVICE_UNAVAILABLE);
    let leftovers: Vec<_> = std::fs::read_dir(data.join("documents"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".part"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    // Space returns: the same upload succeeds and the service is ready again.
    std::fs::remove_file(filler).unwrap();
    expect_json(upload(document_png(200, 200)).await.unwrap(), StatusCode::CREATED).await;
    assert_eq!(app.op_get("/readyz").await.status(), StatusCode::OK);

    app.stop().await;
}
