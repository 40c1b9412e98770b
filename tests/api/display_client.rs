//! The display client (`eyekey display-client`) against the real server: it installs verified bundles into
//! `current/`, says clearly when its token is refused, and rides out the server going away.

use std::path::Path;
use std::time::Duration;

use eyekey::client::{follow, read_state, sync_once, ClientConfig, ClientError, SyncOutcome};
use tokio::sync::oneshot;

use crate::helpers::{myope, spawn_app_in, spawn_app_with, tiny_display, Fixtures, TestApp};

/// Creates a job with fast options and waits until it succeeds; returns its id.
async fn finished_job(app: &TestApp, f: &Fixtures) -> uuid::Uuid {
    let job = app.create_job(f).await;
    let id = job["id"].as_str().unwrap();
    let done = app.wait_for_terminal(id, Duration::from_secs(120)).await;
    assert_eq!(done["state"], "succeeded", "{done}");
    id.parse().unwrap()
}

fn client(app: &TestApp, token: &str, out: &Path) -> ClientConfig {
    ClientConfig::new(&app.address, token, out).unwrap()
}

/// Timings short enough for a test.
fn quick(mut cfg: ClientConfig) -> ClientConfig {
    cfg.backoff_initial = Duration::from_millis(50);
    cfg.backoff_max = Duration::from_millis(300);
    cfg.poll_interval = Duration::from_millis(200);
    cfg
}

/// Waits until `state.json` says `current/` shows `job`.
async fn wait_until_shown(out: &Path, job: uuid::Uuid, timeout: Duration) {
    let deadline = tokio::time::Instant::now() + timeout;
    while read_state(out).current.map(|c| c.job_id) != Some(job) {
        assert!(
            tokio::time::Instant::now() < deadline,
            "job {job} was not installed in time"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn assert_current_is_a_verified_bundle(out: &Path) {
    let current = out.join("current");
    let n_bands = tiny_display().n_bands();
    for n in 0..n_bands {
        assert!(current.join(format!("frame_{n}.png")).is_file(), "frame_{n}.png");
    }
    assert!(current.join("barrier_mask.png").is_file());
    assert!(current.join("manifest.json").is_file());
    let (manifest, l) = eyekey_core::bundle::read_bundle(&current).expect("current/ is a valid bundle");
    assert_eq!(manifest.display, tiny_display());
    assert_eq!(l.len(), tiny_display().n_samples_per_band() * n_bands);
    let leftovers: Vec<_> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(
        leftovers.is_empty(),
        "no temporary files are left behind: {leftovers:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_once_downloads_verifies_and_writes_current_frames() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let out = tempfile::tempdir().unwrap();
    let cfg = client(&app, &f.display_token, out.path());
    assert_eq!(sync_once(&cfg).await.unwrap(), SyncOutcome::NoJobs);

    let first = finished_job(&app, &f).await;
    match sync_once(&cfg).await.unwrap() {
        SyncOutcome::Installed {
            job_id,
            frames,
            preview,
        } => {
            assert_eq!(job_id, first);
            assert_eq!(frames as usize, tiny_display().n_bands());
            assert_eq!(preview, None);
        }
        other => panic!("expected an install, got {other:?}"),
    }
    assert_current_is_a_verified_bundle(out.path());
    let state = read_state(out.path());
    assert_eq!(state.current.as_ref().map(|c| c.job_id), Some(first));
    let state_text = std::fs::read_to_string(out.path().join("state.json")).unwrap();
    assert!(
        !state_text.contains(&f.display_token),
        "the state file never holds the token"
    );

    // Nothing new: nothing is downloaded again.
    assert_eq!(sync_once(&cfg).await.unwrap(), SyncOutcome::UpToDate { job_id: first });

    // A newer job replaces it; the old frames move to previous/.
    let second = finished_job(&app, &f).await;
    assert!(matches!(sync_once(&cfg).await.unwrap(), SyncOutcome::Installed { job_id, .. } if job_id == second));
    assert_current_is_a_verified_bundle(out.path());
    assert!(eyekey_core::bundle::read_bundle(&out.path().join("previous")).is_ok());
    let state = read_state(out.path());
    assert_eq!(state.current.map(|c| c.job_id), Some(second));
    assert_eq!(state.previous.map(|c| c.job_id), Some(first));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_refuses_a_corrupted_bundle_and_keeps_showing_the_last_good_one() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let good = finished_job(&app, &f).await;
    let out = tempfile::tempdir().unwrap();
    let cfg = client(&app, &f.display_token, out.path());
    sync_once(&cfg).await.unwrap();

    // The next bundle is damaged before it was sealed (as if the encoder's output had been): one byte in
    // the middle of the zip (frame data). The server serves what it sealed; the client must catch it.
    let bad = finished_job(&app, &f).await;
    let zip = app
        .data_dir
        .join("jobs")
        .join(format!("{bad}-1"))
        .join("bundle.zip.sealed");
    let key = eyekey::service::sealed::job_key(&app.state.master_key, &app.job_row(&bad.to_string()).await).unwrap();
    let aad = eyekey::service::sealed::job_file_aad(&bad.to_string(), "bundle.zip");
    let mut bytes = key.open(&std::fs::read(&zip).unwrap(), &aad).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x55;
    std::fs::write(&zip, key.seal(&bytes, &aad).unwrap()).unwrap();

    let err = sync_once(&cfg).await.unwrap_err();
    assert!(matches!(err, ClientError::Bundle { job, .. } if job == bad), "{err:?}");
    assert!(
        err.is_retryable(),
        "a download may be damaged in transit: it is tried again"
    );
    assert_eq!(read_state(out.path()).current.map(|c| c.job_id), Some(good));
    assert_current_is_a_verified_bundle(out.path());
    assert!(!out.path().join("previous").exists(), "nothing was swapped");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_writes_what_the_given_person_sees_as_a_preview() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let job = finished_job(&app, &f).await;
    let out = tempfile::tempdir().unwrap();
    let mut cfg = client(&app, &f.display_token, out.path());
    cfg.preview = Some(myope());
    let outcome = sync_once(&cfg).await.unwrap();
    let preview = out.path().join("current").join("preview.png");
    assert_eq!(
        outcome,
        SyncOutcome::Installed {
            job_id: job,
            frames: tiny_display().n_bands() as u32,
            preview: Some(preview.clone())
        }
    );
    let picture = image::open(&preview).expect("preview.png is a PNG").to_rgb8();
    assert!(picture.width() >= tiny_display().holes_x && picture.height() >= tiny_display().holes_y);
    // The preview sits beside the bundle without breaking its verification.
    assert_current_is_a_verified_bundle(out.path());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_with_a_wrong_token_reports_unauthorised() {
    let app = spawn_app_with(|_| {}).await;
    let out = tempfile::tempdir().unwrap();
    let cfg = quick(client(&app, "not-a-display-token", out.path()));
    let err = sync_once(&cfg).await.unwrap_err();
    assert!(matches!(err, ClientError::Unauthorised), "{err:?}");
    assert!(err.to_string().contains("401"), "{err}");
    assert!(!err.is_retryable());

    // Following gives up at once instead of retrying a token that will never work.
    let (_stop, stopped) = oneshot::channel::<()>();
    let result = tokio::time::timeout(
        Duration::from_secs(10),
        follow(&cfg, async { stopped.await.unwrap_or(()) }),
    )
    .await
    .expect("follow returns promptly");
    assert!(matches!(result, Err(ClientError::Unauthorised)), "{result:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_pointed_at_something_that_is_not_eyekey_says_so() {
    let app = spawn_app_with(|_| {}).await;
    let (_, token) = app.register_display().await;
    let out = tempfile::tempdir().unwrap();
    let cfg = ClientConfig::new(&app.url("/not-here"), &token, out.path()).unwrap();
    let err = sync_once(&cfg).await.unwrap_err();
    assert!(matches!(err, ClientError::NoApi { .. }), "{err:?}");
    assert!(err.to_string().contains("404"), "{err}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn display_client_survives_the_server_going_away() {
    // A port with nothing listening yet.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = format!("http://127.0.0.1:{port}");
    let data = tempfile::tempdir().unwrap();
    let out = tempfile::tempdir().unwrap();

    // Before any display exists there is no token to check, so start with a placeholder to see the
    // unreachable server reported as a passing problem.
    let offline = quick(ClientConfig::new(&address, "placeholder", out.path()).unwrap());
    let err = sync_once(&offline).await.unwrap_err();
    assert!(matches!(err, ClientError::Unreachable { .. }), "{err:?}");
    assert!(err.is_retryable());

    // The server comes up, the display is registered, and its client is started.
    let bind = move |c: &mut eyekey::service::Config| {
        c.bind = format!("127.0.0.1:{port}").parse().unwrap();
        c.workers = 1;
    };
    let app = spawn_app_in(data.path(), bind).await;
    let f = app.fixtures().await;
    let cfg = quick(ClientConfig::new(&address, &f.display_token, out.path()).unwrap());
    let (stop, stopped) = oneshot::channel::<()>();
    let follower = {
        let cfg = cfg.clone();
        tokio::spawn(async move { follow(&cfg, async { stopped.await.unwrap_or(()) }).await })
    };

    let first = finished_job(&app, &f).await;
    wait_until_shown(out.path(), first, Duration::from_secs(60)).await;
    assert_current_is_a_verified_bundle(out.path());

    // The server goes away for a while: the client keeps retrying and keeps showing what it has.
    app.stop().await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(
        !follower.is_finished(),
        "the client keeps running while the server is away"
    );
    assert_eq!(read_state(out.path()).current.map(|c| c.job_id), Some(first));
    assert!(eyekey_core::bundle::read_bundle(&out.path().join("current")).is_ok());

    // It comes back on the same port with the same data; the client resumes and installs the next job.
    let app = spawn_app_in(data.path(), bind).await;
    let second = finished_job(&app, &f).await;
    wait_until_shown(out.path(), second, Duration::from_secs(60)).await;
    assert_current_is_a_verified_bundle(out.path());

    // And it stops cleanly when told to.
    stop.send(()).unwrap();
    let result = tokio::time::timeout(Duration::from_secs(10), follower)
        .await
        .expect("the client stops in time");
    assert!(result.unwrap().is_ok());
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_display_client_command_installs_once_and_reports_a_refused_token_on_one_line() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let job = finished_job(&app, &f).await;
    let out = tempfile::tempdir().unwrap();
    let run = |token: String| {
        let (server, out) = (app.address.clone(), out.path().to_path_buf());
        tokio::task::spawn_blocking(move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_eyekey"))
                .args(["display-client", "--once", "--server", &server, "--out"])
                .arg(&out)
                .env("EYEKEY_DISPLAY_TOKEN", token)
                .env("RUST_LOG", "warn")
                .output()
                .unwrap()
        })
    };

    let ok = run(f.display_token.clone()).await.unwrap();
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "{stdout}{}", String::from_utf8_lossy(&ok.stderr));
    assert!(stdout.contains(&format!("installed job {job}")), "{stdout}");
    assert_current_is_a_verified_bundle(out.path());

    let again = run(f.display_token.clone()).await.unwrap();
    assert!(again.status.success());
    assert!(String::from_utf8_lossy(&again.stdout).contains("no new job"));

    let refused = run("wrong-token".into()).await.unwrap();
    assert_eq!(refused.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("401"), "{stderr}");
}
