//! eyekey on PostgreSQL: the flow in one process, and API and worker processes sharing one database.
//!
//! A real PostgreSQL server is started once per test run by `tests/postgres/server.sh` (which installs
//! Debian's package when it is missing, as root), on 127.0.0.1 and a free port, and stopped when the test
//! process ends; `EYEKEY_TEST_POSTGRES_URL` names an existing server instead. Each test gets a database
//! of its own. These tests never skip: without a server they fail, saying why.

use std::io::{BufRead as _, Seek as _};
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use eyekey::service::store::{self, Location};
use reqwest::StatusCode;
use serde_json::{json, Value};
use sqlx::Connection as _;

use crate::helpers::{
    document_png, expect_json, fast_options, myope, read_events, spawn_app_with, tiny_display, OPERATOR_TOKEN,
};

/// The test server's administrative URL (database `postgres`), started on first use.
fn server() -> &'static str {
    static SERVER: OnceLock<String> = OnceLock::new();
    SERVER.get_or_init(|| {
        let given = std::env::var("EYEKEY_TEST_POSTGRES_URL").ok();
        eyekey::research::scale::postgres_server(given.as_deref())
            .unwrap_or_else(|e| panic!("no PostgreSQL for the tests: {e:#}"))
    })
}

/// A new, empty database on the test server.
async fn fresh_database() -> String {
    eyekey::research::scale::fresh_database(server())
        .await
        .unwrap_or_else(|e| panic!("a database on the test PostgreSQL at {}: {e:#}", server()))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_whole_flow_runs_on_postgresql_with_bundles_in_the_database() {
    let url = fresh_database().await;
    let location = Location::parse(&url).unwrap();
    let app = spawn_app_with(|c| {
        c.workers = 1;
        c.database = Some(location.clone());
    })
    .await;
    assert_eq!(app.state.writer.backend(), store::Backend::Postgres);
    crate::flow::whole_flow(&app).await;

    // Nothing went to the data directory but the process's own files; the document and the bundle are
    // sealed rows of `objects`, none holding the document's PNG in clear.
    let mut names: Vec<String> = std::fs::read_dir(&app.data_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(names, ["downloaded.zip", "eyekey.lock", "master.key"]);
    let objects: Vec<(String, Vec<u8>)> = sqlx::query_as("SELECT path, data FROM objects")
        .fetch_all(&app.state.db)
        .await
        .unwrap();
    assert!(objects.iter().any(|(p, _)| p.starts_with("documents/")));
    assert!(objects.iter().any(|(p, _)| p.ends_with("/bundle.zip.sealed")));
    let png = document_png(24, 24);
    for (path, data) in &objects {
        assert!(!data.windows(64).any(|w| png.windows(64).any(|p| p == w)), "{path}");
    }
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deletion_the_audit_log_and_listings_behave_on_postgresql_as_on_sqlite() {
    let url = fresh_database().await;
    let location = Location::parse(&url).unwrap();
    let app = spawn_app_with(|c| c.database = Some(location.clone())).await;
    let f = app.fixtures().await;
    let observer = app.enrol(&myope()).await;
    let mut body = crate::helpers::job_body(&f);
    body["observer_profile_ids"] = json!([observer]);
    let job = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let id = job["id"].as_str().unwrap();
    // The same request under the same key is the same job; a second job lists first.
    let keyed = |b: &Value| {
        app.client
            .post(app.url("/v1/jobs"))
            .bearer_auth(OPERATOR_TOKEN)
            .header("idempotency-key", "k-1")
            .json(b)
            .send()
    };
    let first = expect_json(keyed(&body).await.unwrap(), StatusCode::CREATED).await;
    let again = expect_json(keyed(&body).await.unwrap(), StatusCode::OK).await;
    assert_eq!(first["id"], again["id"]);
    let page = expect_json(app.op_get("/v1/jobs?limit=1").await, StatusCode::OK).await;
    assert_eq!(page["items"][0]["id"], first["id"]);
    let next = page["next_cursor"].as_str().unwrap();
    let page2 = expect_json(
        app.op_get(&format!("/v1/jobs?limit=1&cursor={next}")).await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(page2["items"][0]["id"], id);

    // Deleting the observer's profile deletes the jobs it was an observer of (the JSON query of PostgreSQL).
    let r = app.op_delete(&format!("/v1/profiles/{observer}")).await;
    assert_eq!(r.status(), StatusCode::NO_CONTENT);
    for j in [id, first["id"].as_str().unwrap()] {
        assert_eq!(
            app.op_get(&format!("/v1/jobs/{j}")).await.status(),
            StatusCode::NOT_FOUND
        );
        let (key,): (Option<Vec<u8>>,) = sqlx::query_as("SELECT data_key FROM jobs WHERE id = $1")
            .bind(j)
            .fetch_one(&app.state.db)
            .await
            .unwrap();
        assert!(key.is_none(), "a deleted job's key is destroyed");
    }

    // The audit log is append-only here too.
    let update = sqlx::query("UPDATE audit_log SET actor = 'someone else'")
        .execute(&app.state.db)
        .await;
    assert!(update.unwrap_err().to_string().contains("append-only"));
    let delete = sqlx::query("DELETE FROM audit_log").execute(&app.state.db).await;
    assert!(delete.unwrap_err().to_string().contains("append-only"));
    app.stop().await;
}

/// A master key every process of a test shares.
const MASTER_KEY: &str = "8f4c1e0b7a6d5c4b3a291807f6e5d4c3b2a1908f7e6d5c4b3a29180f7e6d5c4b";

/// An eyekey process (`serve` or `worker`) started from the built binary; killed when dropped.
struct Process {
    child: Child,
    log: PathBuf,
    name: String,
}

impl Process {
    fn start(name: &str, dir: &Path, args: &[&str]) -> Self {
        let data = dir.join(name);
        std::fs::create_dir_all(&data).unwrap();
        let log = dir.join(format!("{name}.log"));
        let out = std::fs::File::create(&log).unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_eyekey"))
            .args(args)
            .arg("--data-dir")
            .arg(&data)
            .env("EYEKEY_MASTER_KEY", MASTER_KEY)
            .env("EYEKEY_OPERATOR_TOKEN", OPERATOR_TOKEN)
            .env("RUST_LOG", "info")
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .spawn()
            .unwrap();
        Self {
            child,
            log,
            name: name.to_string(),
        }
    }

    fn api(name: &str, dir: &Path, url: &str) -> Self {
        Self::start(
            name,
            dir,
            &[
                "serve",
                "--database-url",
                url,
                "--bind",
                "127.0.0.1:0",
                "--workers",
                "0",
            ],
        )
    }

    fn worker(name: &str, dir: &Path, url: &str, lease_secs: u64) -> Self {
        let lease = lease_secs.to_string();
        Self::start(name, dir, &["worker", "--database-url", url, "--lease-secs", &lease])
    }

    /// The log so far.
    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits until the log holds a line containing `needle`; returns that line.
    async fn wait_for_line(&mut self, needle: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let mut reader = std::io::BufReader::new(std::fs::File::open(&self.log).unwrap());
            reader.rewind().unwrap();
            if let Some(line) = reader.lines().map_while(Result::ok).find(|l| l.contains(needle)) {
                return line;
            }
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!(
                    "{} exited ({status}) before saying {needle:?}:\n{}",
                    self.name,
                    self.log()
                );
            }
            assert!(
                Instant::now() < deadline,
                "{} did not say {needle:?} in time:\n{}",
                self.name,
                self.log()
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// For `serve`: waits until it listens; returns its base URL.
    async fn address(&mut self) -> String {
        let line = self.wait_for_line("eyekey serving on ", Duration::from_secs(60)).await;
        let rest = line.split("eyekey serving on ").nth(1).unwrap();
        rest.split_whitespace().next().unwrap().to_string()
    }

    fn kill_9(&mut self) {
        // SAFETY: kill(2) on our own child's pid.
        let r = unsafe { libc::kill(self.child.id() as i32, libc::SIGKILL) };
        assert_eq!(r, 0);
        self.child.wait().unwrap();
    }

    /// SIGTERM, and waits for a graceful exit.
    async fn stop(mut self) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                assert!(status.success(), "{} exited with {status}:\n{}", self.name, self.log());
                return;
            }
            assert!(Instant::now() < deadline, "{} did not stop:\n{}", self.name, self.log());
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An operator's client of an API process.
struct Remote {
    base: String,
    client: reqwest::Client,
}

impl Remote {
    fn new(base: String) -> Self {
        Self {
            base,
            client: reqwest::Client::builder()
                .timeout(Duration::from_secs(60))
                .build()
                .unwrap(),
        }
    }

    async fn post(&self, path: &str, body: &Value) -> Value {
        let r = self
            .client
            .post(format!("{}{path}", self.base))
            .bearer_auth(OPERATOR_TOKEN)
            .json(body)
            .send()
            .await
            .unwrap();
        expect_json(r, StatusCode::CREATED).await
    }

    async fn get(&self, path: &str) -> Value {
        let r = self
            .client
            .get(format!("{}{path}", self.base))
            .bearer_auth(OPERATOR_TOKEN)
            .send()
            .await
            .unwrap();
        expect_json(r, StatusCode::OK).await
    }

    /// A profile, a display (the tiny one, or a preset) and a document: the body of a job with fast options.
    async fn job_body(&self, preset: Option<&str>, document_side: u32) -> Value {
        self.job_body_and_token(preset, document_side).await.0
    }

    /// [`Self::job_body`], and the display's token.
    async fn job_body_and_token(&self, preset: Option<&str>, document_side: u32) -> (Value, String) {
        let profile = self
            .post("/v1/profiles", &json!({ "label": "p", "profile": myope() }))
            .await;
        let display = match preset {
            Some(p) => self.post("/v1/displays", &json!({ "name": p, "preset": p })).await,
            None => {
                self.post("/v1/displays", &json!({ "name": "tiny", "geometry": tiny_display() }))
                    .await
            }
        };
        let r = self
            .client
            .post(format!("{}/v1/documents", self.base))
            .bearer_auth(OPERATOR_TOKEN)
            .header("content-type", "image/png")
            .body(document_png(document_side, document_side))
            .send()
            .await
            .unwrap();
        let document = expect_json(r, StatusCode::CREATED).await;
        let mut options = fast_options();
        options["optics"] = json!("geometric");
        let body = json!({
            "display_id": display["display"]["id"],
            "document_id": document["id"],
            "profile_id": profile["id"],
            "options": options,
        });
        (body, display["token"].as_str().unwrap().to_string())
    }

    /// Queues a job of a few seconds (the `small` preset with an iteration cap the tolerance will not cut
    /// short); returns its id.
    async fn queue_slow_job(&self) -> String {
        let mut body = self.job_body(Some("small"), 48).await;
        body["options"]["max_iterations"] = json!(3000);
        body["options"]["tolerance"] = json!(1e-12);
        self.post("/v1/jobs", &body).await["id"].as_str().unwrap().to_string()
    }

    async fn wait_for_terminal(&self, id: &str, timeout: Duration) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let job = self.get(&format!("/v1/jobs/{id}")).await;
            if matches!(job["state"].as_str(), Some("succeeded" | "failed" | "cancelled")) {
                return job;
            }
            assert!(Instant::now() < deadline, "job {id} did not finish in time: {job}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// The attempt directories of a job's stored outputs.
async fn output_dirs(url: &str, job: &str) -> Vec<String> {
    let mut conn = sqlx::PgConnection::connect(url).await.unwrap();
    let rows: Vec<(String,)> = sqlx::query_as("SELECT path FROM objects WHERE path LIKE $1")
        .bind(format!("jobs/{job}-%"))
        .fetch_all(&mut conn)
        .await
        .unwrap();
    let mut dirs: Vec<String> = rows
        .into_iter()
        .map(|(p,)| p.split('/').take(2).collect::<Vec<_>>().join("/"))
        .collect();
    dirs.sort();
    dirs.dedup();
    dirs
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_killed_mid_solve_loses_nothing_and_the_job_completes_exactly_once() {
    let url = fresh_database().await;
    let dir = tempfile::tempdir().unwrap();
    let mut api = Process::api("api", dir.path(), &url);
    let remote = Remote::new(api.address().await);
    let id = remote.queue_slow_job().await;

    // Worker A alone claims it; once it is solving, B starts and A is killed.
    let mut a = Process::worker("worker-a", dir.path(), &url, 2);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let job = remote.get(&format!("/v1/jobs/{id}")).await;
        if job["state"] == "running" && job["progress"].as_f64().unwrap() > 0.0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "worker A never got going: {job}\n{}",
            a.log()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut b = Process::worker("worker-b", dir.path(), &url, 2);
    b.wait_for_line("eyekey worker running", Duration::from_secs(30)).await;
    a.kill_9();

    let job = remote.wait_for_terminal(&id, Duration::from_secs(180)).await;
    assert_eq!(job["state"], "succeeded", "{job}\nB:\n{}", b.log());
    assert_eq!(job["attempts"], 2, "A's attempt and B's: {job}");
    // One bundle, the second attempt's: A stored nothing, and nothing was completed twice.
    assert_eq!(output_dirs(&url, &id).await, [format!("jobs/{id}-2")]);
    let listing = remote.get(&format!("/v1/jobs/{id}/views")).await;
    assert!(!listing["names"].as_array().unwrap().is_empty());
    let audit = remote.get(&format!("/v1/audit?resource=jobs/{id}")).await;
    let creates = audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "job.create")
        .count();
    assert_eq!(creates, 1);
    b.stop().await;
    api.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_api_processes_and_three_workers_complete_fifty_jobs_each_exactly_once() {
    let url = fresh_database().await;
    let dir = tempfile::tempdir().unwrap();
    // Both API processes start at once: the migrations are applied once, under PostgreSQL's advisory lock.
    let (mut api1, mut api2) = (
        Process::api("api-1", dir.path(), &url),
        Process::api("api-2", dir.path(), &url),
    );
    let apis = [Remote::new(api1.address().await), Remote::new(api2.address().await)];
    let workers: Vec<Process> = (1..=3)
        .map(|n| Process::worker(&format!("worker-{n}"), dir.path(), &url, 30))
        .collect();
    let (body, display_token) = apis[0].job_body_and_token(None, 24).await;
    let mut ids = Vec::new();
    for n in 0..50 {
        // Alternate the API process each job is submitted through.
        ids.push(
            apis[n % 2].post("/v1/jobs", &body).await["id"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    for (n, id) in ids.iter().enumerate() {
        // Followed through the other process than the one it was submitted to.
        let job = apis[(n + 1) % 2].wait_for_terminal(id, Duration::from_secs(600)).await;
        assert_eq!(job["state"], "succeeded", "{job}");
        assert_eq!(job["attempts"], 1, "{job}");
    }
    let mut conn = sqlx::PgConnection::connect(&url).await.unwrap();
    // Each job: one attempt, one bundle, one `job.create` in the audit log; and every worker took part.
    let per_job: Vec<(String, i64, Option<String>, String)> =
        sqlx::query_as("SELECT id, attempts, bundle_path, worker_id FROM jobs ORDER BY id")
            .fetch_all(&mut conn)
            .await
            .unwrap();
    assert_eq!(per_job.len(), 50);
    for (id, attempts, bundle, _) in &per_job {
        assert_eq!(*attempts, 1);
        assert_eq!(bundle.as_deref(), Some(format!("jobs/{id}-1").as_str()));
        assert_eq!(output_dirs(&url, id).await, [format!("jobs/{id}-1")]);
    }
    // The display downloads the same bundle through either API process.
    let mut zips = Vec::new();
    for api in &apis {
        let r = api
            .client
            .get(format!("{}/v1/frames/jobs/{}/bundle.zip", api.base, ids[7]))
            .bearer_auth(&display_token)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::OK);
        zips.push(r.bytes().await.unwrap());
    }
    assert!(!zips[0].is_empty());
    assert_eq!(zips[0], zips[1]);
    let workers_used: std::collections::HashSet<&str> = per_job.iter().map(|(_, _, _, w)| w.as_str()).collect();
    assert_eq!(workers_used.len(), 3, "all three workers ran jobs");
    let (creates,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM audit_log WHERE action = 'job.create'")
        .fetch_one(&mut conn)
        .await
        .unwrap();
    assert_eq!(creates, 50);
    let (migrations,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM _sqlx_migrations")
        .fetch_one(&mut conn)
        .await
        .unwrap();
    assert_eq!(migrations as usize, store::POSTGRES_MIGRATOR.iter().count());
    for w in workers {
        w.stop().await;
    }
    api2.stop().await;
    api1.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_started_before_the_api_waits_for_the_schema_then_runs_jobs() {
    let url = fresh_database().await;
    let dir = tempfile::tempdir().unwrap();
    let mut worker = Process::worker("worker", dir.path(), &url, 30);
    worker
        .wait_for_line("waiting for the database", Duration::from_secs(30))
        .await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(
        worker.child.try_wait().unwrap().is_none(),
        "the worker waits:\n{}",
        worker.log()
    );
    let mut conn = sqlx::PgConnection::connect(&url).await.unwrap();
    let tables: Vec<(String,)> = sqlx::query_as("SELECT tablename::text FROM pg_tables WHERE schemaname = 'public'")
        .fetch_all(&mut conn)
        .await
        .unwrap();
    assert!(tables.is_empty(), "the worker created no schema: {tables:?}");
    // A worker without the master key is refused at once: it never makes one.
    let bare = dir.path().join("bare");
    std::fs::create_dir_all(&bare).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_eyekey"))
        .args(["worker", "--database-url", &url, "--data-dir"])
        .arg(&bare)
        .env_remove("EYEKEY_MASTER_KEY")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("needs the master key"));

    let mut api = Process::api("api", dir.path(), &url);
    let remote = Remote::new(api.address().await);
    worker
        .wait_for_line("eyekey worker running", Duration::from_secs(60))
        .await;
    let (body, display_token) = remote.job_body_and_token(None, 24).await;
    // The display's stream and the job's stream, through the API process, follow a job that a worker in
    // another process runs (the change feed: LISTEN/NOTIFY).
    let get = |path: String, token: &str| {
        remote
            .client
            .get(format!("{}{path}", remote.base))
            .bearer_auth(token)
            .send()
    };
    let display_events = get("/v1/frames/events".into(), &display_token).await.unwrap();
    let notified = tokio::spawn(read_events(display_events, Duration::from_secs(120), |name, _| {
        name == "job_succeeded"
    }));
    let id = remote.post("/v1/jobs", &body).await["id"].as_str().unwrap().to_string();
    let stream = get(format!("/v1/jobs/{id}/events"), OPERATOR_TOKEN).await.unwrap();
    let events = read_events(stream, Duration::from_secs(120), |_, v| {
        matches!(v["state"].as_str(), Some("succeeded" | "failed" | "cancelled"))
    })
    .await;
    let last = &events.last().expect("job events arrive").1;
    assert_eq!(last["state"], "succeeded", "{last}\n{}", worker.log());
    let note = notified.await.unwrap();
    assert_eq!(
        note.last().map(|(_, v)| v["id"].as_str().unwrap()),
        Some(id.as_str()),
        "the display hears of the bundle"
    );
    worker.stop().await;
    api.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_stopped_gracefully_requeues_its_job_without_counting_the_attempt() {
    let url = fresh_database().await;
    let dir = tempfile::tempdir().unwrap();
    let mut api = Process::api("api", dir.path(), &url);
    let remote = Remote::new(api.address().await);
    let id = remote.queue_slow_job().await;
    let a = Process::worker("worker-a", dir.path(), &url, 30);
    let deadline = Instant::now() + Duration::from_secs(60);
    while remote.get(&format!("/v1/jobs/{id}")).await["state"] != "running" {
        assert!(Instant::now() < deadline, "the job never started:\n{}", a.log());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // SIGTERM: the worker stops its solve and puts the job back, its attempt not counted.
    a.stop().await;
    let job = remote.get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(
        (job["state"].as_str(), job["attempts"].as_i64()),
        (Some("queued"), Some(0)),
        "{job}"
    );
    // Another worker then runs it to the end in one attempt (its lease is 30 s: no wait for an expiry).
    let b = Process::worker("worker-b", dir.path(), &url, 30);
    let job = remote.wait_for_terminal(&id, Duration::from_secs(180)).await;
    assert_eq!(job["state"], "succeeded", "{job}\n{}", b.log());
    assert_eq!(job["attempts"], 1);
    assert_eq!(output_dirs(&url, &id).await, [format!("jobs/{id}-1")]);
    b.stop().await;
    api.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_processes_starting_at_the_same_moment_share_one_schema_and_one_master_key() {
    for _round in 0..5 {
        let url = fresh_database().await;
        let dir = tempfile::tempdir().unwrap();
        let mut apis: Vec<Process> = (1..=4)
            .map(|n| Process::api(&format!("api-{n}"), dir.path(), &url))
            .collect();
        for api in &mut apis {
            api.address().await;
        }
        let mut conn = sqlx::PgConnection::connect(&url).await.unwrap();
        let (migrations,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM _sqlx_migrations WHERE success")
            .fetch_one(&mut conn)
            .await
            .unwrap();
        assert_eq!(migrations as usize, store::POSTGRES_MIGRATOR.iter().count());
        let (sentinels,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM settings")
            .fetch_one(&mut conn)
            .await
            .unwrap();
        assert_eq!(sentinels, 1);
        for api in apis {
            api.stop().await;
        }
    }
    // A process with another master key is refused, naming the reason.
    let url = fresh_database().await;
    let dir = tempfile::tempdir().unwrap();
    let mut first = Process::api("first", dir.path(), &url);
    first.address().await;
    let data = dir.path().join("other");
    std::fs::create_dir_all(&data).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_eyekey"))
        .args(["worker", "--database-url", &url, "--data-dir"])
        .arg(&data)
        .env("EYEKEY_MASTER_KEY", "11".repeat(32))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("master key does not match"), "{stderr}");
    first.stop().await;
}
