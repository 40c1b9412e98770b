use std::time::Duration;

use reqwest::StatusCode;

use crate::helpers::{expect_json, spawn_app_in};

#[tokio::test]
async fn everything_survives_a_restart_on_the_same_data_directory() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let f = app.fixtures().await;
    let job = app.create_job(&f).await;
    app.stop().await;

    let app = spawn_app_in(dir.path(), |_| {}).await;
    let profile = expect_json(
        app.op_get(&format!("/v1/profiles/{}", f.profile_id)).await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(
        profile["profile"]["zernike_um"][7], 0.123456789,
        "the master key file is reused"
    );
    assert_eq!(
        app.display_get(&f.display_token, "/v1/frames/jobs").await.status(),
        StatusCode::OK
    );
    let again = app.job(job["id"].as_str().unwrap()).await;
    assert_eq!(again["state"], "queued", "a queued job is still queued");
}

/// Stops the server while a job is being solved and starts a new one on the same data directory: the
/// job is re-queued on shutdown without losing an attempt and completes exactly once. Runs the real
/// encoder.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_running_at_shutdown_completes_exactly_once_after_restart() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |c| c.workers = 1).await;
    let id = app.start_slow_job().await;
    app.stop().await;

    // On shutdown the running job was cancelled and put back in the queue, its attempt not counted.
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let job = app.job(&id).await;
    assert_eq!(
        (job["state"].as_str(), job["attempts"].as_i64()),
        (Some("queued"), Some(0)),
        "{job}"
    );
    app.stop().await;

    let app = spawn_app_in(dir.path(), |c| c.workers = 1).await;
    let job = app.wait_for_terminal(&id, Duration::from_secs(120)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 1, "the interrupted attempt is not counted");
    let outputs: Vec<_> = std::fs::read_dir(dir.path().join("jobs"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        outputs,
        vec![std::ffi::OsString::from(format!("{id}-1"))],
        "one output, no temporary leftovers"
    );
    let succeeded: (i64,) = sqlx::query_as("SELECT COUNT(*) FROM jobs WHERE state = 'succeeded'")
        .fetch_one(&app.state.db)
        .await
        .unwrap();
    assert_eq!(succeeded.0, 1);
}

/// A worker that dies without a word (a crashed process) holds its lease until it expires; then a
/// live worker claims the job again and finishes it. Runs the real encoder.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_abandoned_by_a_crashed_worker_is_finished_by_another_after_its_lease() {
    use eyekey::service::store;
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let lease = Duration::from_millis(300);
    let claimed = store::jobs::claim_next(&app.state.writer, "crashed-worker", lease, store::now_ms())
        .await
        .unwrap();
    assert_eq!(claimed.map(|j| j.id.to_string()), Some(id.clone()));
    app.stop().await;

    let app = spawn_app_in(dir.path(), |c| c.workers = 1).await;
    let job = app.wait_for_terminal(&id, Duration::from_secs(60)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 2, "the crashed attempt counts");
}

/// A SIGTERM sent the moment `eyekey serve` says it is serving stops it gracefully (exit 0), not by the signal's
/// default action, which kills the process: the signals are listened for before it says so.
#[test]
fn a_sigterm_as_soon_as_the_server_says_it_serves_stops_it_gracefully() {
    use std::io::BufRead as _;
    for _ in 0..3 {
        let dir = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_eyekey"))
            .args(["serve", "--bind", "127.0.0.1:0", "--workers", "0", "--data-dir"])
            .arg(dir.path())
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
        let mut log = Vec::new();
        for line in lines.by_ref() {
            let line = line.unwrap();
            let serving = line.contains("eyekey serving on ");
            log.push(line);
            if serving {
                // SAFETY: kill(2) on our own child's pid.
                assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
                break;
            }
        }
        // Read on to the end, so the server's last lines are not written into a closed pipe.
        log.extend(lines.map_while(Result::ok));
        let status = child.wait().unwrap();
        assert!(status.success(), "exited with {status}:\n{}", log.join("\n"));
        assert!(log.iter().any(|l| l.contains("eyekey stopped")), "{}", log.join("\n"));
    }
}
