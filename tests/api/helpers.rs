//! Test harness: every test gets its own server on 127.0.0.1:0, its own data directory (a real SQLite
//! file) and a real HTTP client.

use std::path::{Path, PathBuf};
use std::time::Duration;

use eyekey::service::store;
use eyekey::service::{AppState, Application, Config, ShutdownHandle};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::profile::VisionProfile;
use reqwest::{Response, StatusCode};
use serde_json::{json, Value};
use tokio::task::JoinHandle;

pub const OPERATOR_TOKEN: &str = "test-operator-token";

/// A running server.
pub struct TestApp {
    pub address: String,
    pub client: reqwest::Client,
    pub state: AppState,
    pub data_dir: PathBuf,
    _tmp: Option<tempfile::TempDir>,
    shutdown: ShutdownHandle,
    server: JoinHandle<anyhow::Result<()>>,
}

fn init_tracing() {
    if std::env::var_os("TEST_LOG").is_some() {
        let _ = tracing_subscriber::fmt()
            .with_env_filter("info,eyekey=debug")
            .with_test_writer()
            .try_init();
    }
}

/// A test configuration: port 0, no workers (tests drain the queue by hand), the fixed operator token,
/// a master key generated into the data directory.
pub fn test_config(data_dir: &Path) -> Config {
    let mut config = Config::new(data_dir);
    config.bind = "127.0.0.1:0".parse().unwrap();
    config.operator_token = Some(OPERATOR_TOKEN.into());
    config.workers = 0;
    config.queue.poll_interval = Duration::from_millis(50);
    config.queue.shutdown_grace = Duration::from_secs(10);
    config
}

/// A server with the test configuration in a fresh temporary directory.
pub async fn spawn_app() -> TestApp {
    spawn_app_with(|_| {}).await
}

/// A server in a fresh temporary directory, with the test configuration adjusted by `configure`.
pub async fn spawn_app_with(configure: impl FnOnce(&mut Config)) -> TestApp {
    let tmp = tempfile::tempdir().unwrap();
    let mut app = spawn_app_in(tmp.path(), configure).await;
    app._tmp = Some(tmp);
    app
}

/// A server on an existing data directory.
pub async fn spawn_app_in(data_dir: &Path, configure: impl FnOnce(&mut Config)) -> TestApp {
    init_tracing();
    let mut config = test_config(data_dir);
    configure(&mut config);
    let app = Application::build(config).await.expect("the application builds");
    let address = format!("{}://127.0.0.1:{}", app.scheme(), app.port());
    let state = app.state();
    let shutdown = app.shutdown_handle();
    let server = tokio::spawn(app.run_until_stopped());
    TestApp {
        address,
        client: reqwest::Client::builder()
            .timeout(Duration::from_secs(60))
            .build()
            .unwrap(),
        state,
        data_dir: data_dir.to_path_buf(),
        _tmp: None,
        shutdown,
        server,
    }
}

impl TestApp {
    pub fn url(&self, path: &str) -> String {
        format!("{}{}", self.address, path)
    }

    /// Stops the server gracefully and waits for it.
    pub async fn stop(self) {
        self.shutdown.shutdown();
        tokio::time::timeout(Duration::from_secs(30), self.server)
            .await
            .expect("the server stops in time")
            .unwrap()
            .unwrap();
    }

    pub async fn op_get(&self, path: &str) -> Response {
        self.client
            .get(self.url(path))
            .bearer_auth(OPERATOR_TOKEN)
            .send()
            .await
            .unwrap()
    }

    pub async fn op_post(&self, path: &str, body: &Value) -> Response {
        self.client
            .post(self.url(path))
            .bearer_auth(OPERATOR_TOKEN)
            .json(body)
            .send()
            .await
            .unwrap()
    }

    pub async fn op_put(&self, path: &str, body: &Value) -> Response {
        self.client
            .put(self.url(path))
            .bearer_auth(OPERATOR_TOKEN)
            .json(body)
            .send()
            .await
            .unwrap()
    }

    pub async fn op_delete(&self, path: &str) -> Response {
        self.client
            .delete(self.url(path))
            .bearer_auth(OPERATOR_TOKEN)
            .send()
            .await
            .unwrap()
    }

    pub async fn display_get(&self, token: &str, path: &str) -> Response {
        self.client.get(self.url(path)).bearer_auth(token).send().await.unwrap()
    }

    /// Enrols a profile; returns its id.
    pub async fn enrol(&self, profile: &VisionProfile) -> String {
        let r = self
            .op_post("/v1/profiles", &json!({ "label": "test person", "profile": profile }))
            .await;
        let body = expect_json(r, StatusCode::CREATED).await;
        body["id"].as_str().unwrap().to_string()
    }

    /// Registers a tiny display; returns (id, token).
    pub async fn register_display(&self) -> (String, String) {
        let r = self
            .op_post(
                "/v1/displays",
                &json!({ "name": "bench display", "geometry": tiny_display() }),
            )
            .await;
        let body = expect_json(r, StatusCode::CREATED).await;
        (
            body["display"]["id"].as_str().unwrap().to_string(),
            body["token"].as_str().unwrap().to_string(),
        )
    }

    /// Uploads a PNG document; returns its id.
    pub async fn upload(&self, png: Vec<u8>) -> String {
        let r = self
            .client
            .post(self.url("/v1/documents"))
            .bearer_auth(OPERATOR_TOKEN)
            .header("content-type", "image/png")
            .body(png)
            .send()
            .await
            .unwrap();
        let body = expect_json(r, StatusCode::CREATED).await;
        body["id"].as_str().unwrap().to_string()
    }

    /// Enrols a profile, registers a display and uploads a document: (profile, display, token, document).
    pub async fn fixtures(&self) -> Fixtures {
        let profile_id = self.enrol(&myope()).await;
        let (display_id, display_token) = self.register_display().await;
        let document_id = self.upload(document_png(24, 24)).await;
        Fixtures {
            profile_id,
            display_id,
            display_token,
            document_id,
        }
    }

    /// Creates a job with fast options; returns the job JSON.
    pub async fn create_job(&self, f: &Fixtures) -> Value {
        let r = self.op_post("/v1/jobs", &job_body(f)).await;
        expect_json(r, StatusCode::CREATED).await
    }

    pub async fn job(&self, id: &str) -> Value {
        expect_json(self.op_get(&format!("/v1/jobs/{id}")).await, StatusCode::OK).await
    }

    /// Polls a job until it reaches a terminal state.
    pub async fn wait_for_terminal(&self, id: &str, timeout: Duration) -> Value {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let job = self.job(id).await;
            if matches!(job["state"].as_str(), Some("succeeded" | "failed" | "cancelled")) {
                return job;
            }
            assert!(
                tokio::time::Instant::now() < deadline,
                "job {id} did not finish in time: {job}"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    /// Creates a job that takes a few seconds to solve (the 24×24-hole preset and an iteration cap the
    /// tolerance will not cut short), and waits until a worker runs it. Returns its id.
    pub async fn start_slow_job(&self) -> String {
        let mut f = self.fixtures().await;
        let r = self
            .op_post("/v1/displays", &json!({ "name": "small", "preset": "small" }))
            .await;
        f.display_id = expect_json(r, StatusCode::CREATED).await["display"]["id"]
            .as_str()
            .unwrap()
            .to_string();
        f.document_id = self.upload(document_png(48, 48)).await;
        let mut body = job_body(&f);
        body["options"]["max_iterations"] = json!(3000);
        body["options"]["tolerance"] = json!(1e-12);
        // Its length comes from the iteration cap; the geometric model keeps it to seconds.
        body["options"]["optics"] = json!("geometric");
        let r = self.op_post("/v1/jobs", &body).await;
        let id = expect_json(r, StatusCode::CREATED).await["id"]
            .as_str()
            .unwrap()
            .to_string();
        let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
        loop {
            let job = self.job(&id).await;
            if job["state"] == "running" {
                return id;
            }
            assert_eq!(job["state"], "queued", "{job}");
            assert!(tokio::time::Instant::now() < deadline, "the job never started");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// A live job's row as stored.
    pub async fn job_row(&self, id: &str) -> store::jobs::JobRow {
        store::jobs::get(&self.state.db, id.parse().unwrap())
            .await
            .unwrap()
            .expect("a live job")
    }

    /// Claims the next job directly and completes it with a hand-made bundle (frames, mask, manifest,
    /// report and a view), as a worker would after a successful solve. Returns the job id.
    pub async fn complete_with_fake_bundle(&self) -> String {
        let job = store::jobs::claim_next(
            &self.state.writer,
            "test-worker",
            Duration::from_secs(30),
            store::now_ms(),
        )
        .await
        .unwrap()
        .expect("a queued job");
        let relative = format!("jobs/{}-{}", job.id, job.attempts);
        let mut outputs: Vec<(String, Vec<u8>)> = ["frame_0.png", "frame_1.png", "barrier_mask.png"]
            .iter()
            .map(|n| (n.to_string(), document_png(4, 4)))
            .collect();
        outputs.push(("manifest.json".into(), br#"{"files": []}"#.to_vec()));
        outputs.push((
            "report.json".into(),
            br#"{"summary": {"target_psnr_db": 30.0}}"#.to_vec(),
        ));
        outputs.push(("views/target.png".into(), document_png(4, 4)));
        let id = job.id.to_string();
        let key = eyekey::service::sealed::job_key(&self.state.master_key, &job).unwrap();
        let (files, sealed) = eyekey::service::jobs::seal_outputs(&key, &id, &outputs).unwrap();
        self.state.objects.write_dir(&relative, sealed).await.unwrap();
        let ok = store::jobs::mark_succeeded(
            &self.state.writer,
            job.id,
            job.attempts,
            &store::jobs::Success {
                sealed_summary: Some(
                    key.seal(
                        br#"{"target_psnr_db": 30.0}"#,
                        &eyekey::service::sealed::job_summary_aad(&id),
                    )
                    .unwrap(),
                ),
                bundle_path: relative,
                bundle_files: serde_json::to_string(&files).unwrap(),
                solve_ms: 5,
            },
        )
        .await
        .unwrap();
        assert!(ok);
        job.id.to_string()
    }
}

/// The ids made by [`TestApp::fixtures`].
pub struct Fixtures {
    pub profile_id: String,
    pub display_id: String,
    pub display_token: String,
    pub document_id: String,
}

/// A job body with options that make the solve fast.
pub fn job_body(f: &Fixtures) -> Value {
    json!({
        "display_id": f.display_id,
        "document_id": f.document_id,
        "profile_id": f.profile_id,
        "options": fast_options(),
    })
}

/// Options that make the solve fast: five iterations on a display too small to resolve its views, whose target
/// cannot read the result, delivered anyway (`ensure_target_reads: false`, the operator's explicit acceptance),
/// for the tests of everything around the encoder. `jobs::a_job_whose_target_cannot_read_its_frames_fails_*`
/// holds the same job with the guard on.
pub fn fast_options() -> Value {
    json!({
        "max_iterations": 5,
        "sub_rays": 2,
        "population_decoys": 1,
        "near_pupil_decoys": 0,
        "evaluation_population": 2,
        "ensure_target_reads": false,
    })
}

/// A 12×12-hole display with the `small` preset's optics: fast to solve.
pub fn tiny_display() -> DisplayGeometry {
    DisplayGeometry {
        aperture: Default::default(),
        holes_x: 12,
        holes_y: 12,
        ..DisplayGeometry::small()
    }
}

/// A mildly myopic eye with a distinctive coma coefficient.
pub fn myope() -> VisionProfile {
    let mut p = VisionProfile::perfect();
    p.zernike_um[4] = 1.25;
    p.zernike_um[7] = 0.123456789;
    p
}

/// A PNG with a dark bar on a light background.
pub fn document_png(w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        if y >= h / 3 && y < 2 * h / 3 && x > w / 8 && x < 7 * w / 8 {
            image::Rgb([20, 20, 20])
        } else {
            image::Rgb([235, 235, 235])
        }
    });
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .unwrap();
    out
}

/// A syntactically valid PNG whose header claims `w`×`h` pixels but holds almost no data.
pub fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = 0xffff_ffffu32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xedb8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend_from_slice(data);
        out.extend_from_slice(&body);
        out.extend_from_slice(&crc32(&body).to_be_bytes());
    }
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB, deflate, no filter, no interlace
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(&mut out, b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    chunk(&mut out, b"IEND", &[]);
    out
}

/// Asserts the status and returns the JSON body.
pub async fn expect_json(r: Response, status: StatusCode) -> Value {
    let got = r.status();
    let text = r.text().await.unwrap();
    assert_eq!(got, status, "unexpected status; body: {text}");
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
}

/// Asserts an error response: status, the error shape, and its code; returns the error object.
pub async fn expect_error(r: Response, status: StatusCode, code: &str) -> Value {
    let body = expect_json(r, status).await;
    let error = &body["error"];
    assert_eq!(error["code"], code, "{body}");
    assert!(error["message"].as_str().is_some_and(|m| !m.is_empty()), "{body}");
    assert!(
        error.get("field").is_some(),
        "the error shape always has `field`: {body}"
    );
    error.clone()
}

/// Reads server-sent events until `stop` says so or the timeout passes; returns (event, data) pairs.
pub async fn read_events(
    r: Response,
    timeout: Duration,
    mut stop: impl FnMut(&str, &Value) -> bool,
) -> Vec<(String, Value)> {
    use futures::StreamExt as _;
    let mut stream = r.bytes_stream();
    let mut buffer = String::new();
    let mut events = Vec::new();
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        let chunk = match tokio::time::timeout_at(deadline, stream.next()).await {
            Ok(Some(Ok(c))) => c,
            _ => return events,
        };
        buffer.push_str(&String::from_utf8_lossy(&chunk));
        while let Some(end) = buffer.find("\n\n") {
            let block: String = buffer.drain(..end + 2).collect();
            let mut name = String::from("message");
            let mut data = String::new();
            for line in block.lines() {
                if let Some(v) = line.strip_prefix("event:") {
                    name = v.trim().to_string();
                } else if let Some(v) = line.strip_prefix("data:") {
                    data.push_str(v.trim_start());
                }
            }
            if data.is_empty() {
                continue; // keep-alive comment
            }
            let value: Value = serde_json::from_str(&data).unwrap();
            let done = stop(&name, &value);
            events.push((name, value));
            if done {
                return events;
            }
        }
    }
}
