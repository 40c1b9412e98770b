//! Secrets at rest: what the service serves never lies in clear in its data directory, deleting destroys,
//! and data expires.

use std::path::Path;
use std::time::Duration;

use rand::{Rng as _, SeedableRng as _};
use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::{expect_json, fast_options, myope, spawn_app, spawn_app_in, spawn_app_with, TestApp};

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

/// Every file under `dir`, the database and its write-ahead log included: (path, bytes).
fn every_file(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(every_file(&path));
        } else if let Ok(bytes) = std::fs::read(&path) {
            out.push((path.display().to_string(), bytes));
        }
    }
    out
}

/// Asserts that no file under `dir` holds any of a few `width`-byte windows of `secret` (from its middle
/// and end, so that headers shared by every PNG are not taken for the secret).
fn assert_nowhere_in_clear(dir: &Path, what: &str, secret: &[u8], width: usize) {
    assert!(secret.len() >= 2 * width, "{what} is too short to sample");
    let windows = [secret.len() / 3, secret.len() / 2, secret.len() - width].map(|at| &secret[at..at + width]);
    for (path, bytes) in every_file(dir) {
        for w in windows {
            assert!(!contains(&bytes, w), "{path} holds {what} in the clear");
        }
    }
}

/// A PNG of random pixels: its bytes and its raw pixel rows are unlike anything else on the disk.
fn noise_png(w: u32, h: u32, seed: u64) -> (Vec<u8>, Vec<u8>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let img = image::RgbImage::from_fn(w, h, |_, _| image::Rgb([rng.gen(), rng.gen(), rng.gen()]));
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png).unwrap();
    (png.into_inner(), img.into_raw())
}

async fn bytes_of(r: reqwest::Response) -> Vec<u8> {
    assert_eq!(r.status(), StatusCode::OK, "{}", r.url());
    r.bytes().await.unwrap().to_vec()
}

async fn finished(app: &TestApp, body: &Value) -> String {
    let r = app.op_post("/v1/jobs", body).await;
    let id = expect_json(r, StatusCode::CREATED).await["id"]
        .as_str()
        .unwrap()
        .to_string();
    let job = app.wait_for_terminal(&id, Duration::from_secs(120)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    id
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_the_service_serves_lies_in_clear_in_its_data_directory() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let mut f = app.fixtures().await;
    let (png, pixels) = noise_png(48, 48, 7);
    f.document_id = app.upload(png.clone()).await;
    let id = finished(&app, &crate::helpers::job_body(&f)).await;

    let mut served: Vec<(String, Vec<u8>)> = Vec::new();
    served.push((
        "report.json".into(),
        bytes_of(app.op_get(&format!("/v1/jobs/{id}/evaluation")).await).await,
    ));
    let views = expect_json(app.op_get(&format!("/v1/jobs/{id}/views")).await, StatusCode::OK).await;
    let views: Vec<String> = serde_json::from_value(views["names"].clone()).unwrap();
    assert!(views.iter().any(|v| v == "target.png"), "{views:?}");
    for v in &views {
        served.push((
            format!("view {v}"),
            bytes_of(app.op_get(&format!("/v1/jobs/{id}/views/{v}")).await).await,
        ));
    }
    let frames = expect_json(
        app.display_get(&f.display_token, &format!("/v1/frames/jobs/{id}"))
            .await,
        StatusCode::OK,
    )
    .await;
    for file in frames["files"].as_array().unwrap() {
        let name = file["name"].as_str().unwrap();
        let path = format!("/v1/frames/jobs/{id}/files/{name}");
        served.push((
            name.to_string(),
            bytes_of(app.display_get(&f.display_token, &path).await).await,
        ));
    }
    let zip_path = format!("/v1/frames/jobs/{id}/bundle.zip");
    served.push((
        "bundle.zip".into(),
        bytes_of(app.display_get(&f.display_token, &zip_path).await).await,
    ));
    assert!(served.len() >= 7, "report, views, frames, mask, manifest, zip");

    assert_nowhere_in_clear(&app.data_dir, "the uploaded document", &png, 32);
    assert_nowhere_in_clear(&app.data_dir, "the document's pixels", &pixels, 48);
    for (what, bytes) in &served {
        assert_nowhere_in_clear(&app.data_dir, what, bytes, 32.min(bytes.len() / 2));
    }
    for (path, _) in every_file(&app.data_dir.join("jobs"))
        .iter()
        .chain(&every_file(&app.data_dir.join("documents")))
    {
        assert!(path.ends_with(".sealed"), "{path} is not sealed");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn neither_the_manifest_nor_the_database_holds_the_document_text_or_a_hash_of_the_document() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let display = eyekey_core::physics::display::DisplayGeometry {
        holes_x: 28,
        holes_y: 28,
        ..crate::helpers::tiny_display()
    };
    let r = app
        .op_post("/v1/displays", &json!({ "name": "pin display", "geometry": display }))
        .await;
    let registered = expect_json(r, StatusCode::CREATED).await;
    let (display_id, token) = (
        registered["display"]["id"].as_str().unwrap().to_string(),
        registered["token"].as_str().unwrap().to_string(),
    );
    let slip = eyekey_core::imaging::glyphs::render_text(&["PIN", "4821"], 112, 112, 4);
    let mut png = std::io::Cursor::new(Vec::new());
    slip.write_to(&mut png, image::ImageFormat::Png).unwrap();
    let png = png.into_inner();
    let document_id = app.upload(png.clone()).await;
    let mut options = fast_options();
    options["optics"] = json!("geometric");
    options["document_text"] = json!({"lines": ["PIN", "4821"], "scale": 4, "alphabet": "0123456789"});
    let body = json!({
        "display_id": display_id, "document_id": document_id, "profile_id": f.profile_id, "options": options,
    });
    let id = finished(&app, &body).await;

    // The operator who submitted it reads the hint back.
    let job = app.job(&id).await;
    assert_eq!(job["options"]["document_text"]["lines"][1], "4821");
    // The display learns nothing of the document but its frames.
    let manifest = bytes_of(
        app.display_get(&token, &format!("/v1/frames/jobs/{id}/files/manifest.json"))
            .await,
    )
    .await;
    let text = String::from_utf8(manifest).unwrap();
    use sha2::Digest as _;
    for leak in [
        "4821".to_string(),
        "document_text".into(),
        "document_sha256".into(),
        hex::encode(sha2::Sha256::digest(slip.as_raw())),
        hex::encode(sha2::Sha256::digest(&png)),
    ] {
        assert!(!text.contains(&leak), "the manifest holds {leak}: {text}");
    }
    // Nor does anything at rest.
    for (path, bytes) in every_file(&app.data_dir) {
        assert!(!contains(&bytes, b"\"4821\""), "{path} holds the PIN");
        for digest in [sha2::Sha256::digest(&png), sha2::Sha256::digest(slip.as_raw())] {
            assert!(
                !contains(&bytes, hex::encode(digest).as_bytes()),
                "{path} holds a plain hash"
            );
            assert!(!contains(&bytes, &digest), "{path} holds a plain hash");
        }
    }
}

/// The wrapped data keys of a job and a document, as stored.
async fn keys_of(app: &TestApp, job: &str, document: &str) -> (Vec<u8>, Vec<u8>) {
    let (job_key,): (Vec<u8>,) = sqlx::query_as("SELECT data_key FROM jobs WHERE id = $1")
        .bind(job)
        .fetch_one(&app.state.db)
        .await
        .unwrap();
    let (doc_key,): (Vec<u8>,) = sqlx::query_as("SELECT data_key FROM documents WHERE id = $1")
        .bind(document)
        .fetch_one(&app.state.db)
        .await
        .unwrap();
    (job_key, doc_key)
}

#[tokio::test]
async fn deleting_a_document_destroys_its_key_its_file_and_every_job_that_showed_it() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let id = app.complete_with_fake_bundle().await;
    let (job_key, doc_key) = keys_of(&app, &id, &f.document_id).await;
    let job_dir = app.data_dir.join(format!("jobs/{id}-1"));
    let doc_file = app.data_dir.join(format!("documents/{}.sealed", f.document_id));
    assert!(job_dir.is_dir() && doc_file.is_file());

    let r = app.op_delete(&format!("/v1/documents/{}", f.document_id)).await;
    assert_eq!(r.status(), StatusCode::NO_CONTENT);
    for path in [format!("/v1/documents/{}", f.document_id), format!("/v1/jobs/{id}")] {
        assert_eq!(app.op_get(&path).await.status(), StatusCode::NOT_FOUND, "{path}");
    }
    let frames = format!("/v1/frames/jobs/{id}/files/frame_0.png");
    assert_eq!(
        app.display_get(&f.display_token, &frames).await.status(),
        StatusCode::NOT_FOUND
    );
    let listed = expect_json(
        app.display_get(&f.display_token, "/v1/frames/jobs").await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(listed["items"], json!([]));
    assert!(!job_dir.exists() && !doc_file.exists(), "the sealed files are removed");
    // The keys are gone from the database and from its log.
    for (path, bytes) in every_file(&app.data_dir) {
        assert!(
            !contains(&bytes, &job_key) && !contains(&bytes, &doc_key),
            "{path} holds a deleted key"
        );
    }
    let wal = std::fs::metadata(app.data_dir.join("eyekey.db-wal"))
        .map(|m| m.len())
        .unwrap_or(0);
    assert_eq!(wal, 0, "the log was checkpointed and truncated");
    let audit = expect_json(app.op_get("/v1/audit?limit=200").await, StatusCode::OK).await;
    let actions: Vec<&str> = audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["action"].as_str().unwrap())
        .collect();
    assert!(
        actions.contains(&"document.delete") && actions.contains(&"job.delete"),
        "{actions:?}"
    );
    // A second delete finds nothing.
    let r = app.op_delete(&format!("/v1/documents/{}", f.document_id)).await;
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn deleting_a_profile_leaves_no_copy_of_its_ciphertext_and_deletes_the_jobs_derived_from_it() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let observer = app.enrol(&myope()).await;
    let mut body = crate::helpers::job_body(&f);
    body["observer_profile_ids"] = json!([observer]);
    expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let id = app.complete_with_fake_bundle().await;
    let (ciphertext,): (Vec<u8>,) = sqlx::query_as("SELECT ciphertext FROM profile_versions WHERE profile_id = $1")
        .bind(&observer)
        .fetch_one(&app.state.db)
        .await
        .unwrap();

    // Deleting the observer (not the target) takes the job: it was derived from the observer's eyes too.
    assert_eq!(
        app.op_delete(&format!("/v1/profiles/{observer}")).await.status(),
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        app.op_get(&format!("/v1/jobs/{id}")).await.status(),
        StatusCode::NOT_FOUND
    );
    assert!(!app.data_dir.join(format!("jobs/{id}-1")).exists());
    for (path, bytes) in every_file(&app.data_dir) {
        assert!(
            !contains(&bytes, &ciphertext[..32]),
            "{path} holds the deleted profile's ciphertext"
        );
    }
    // The target and the document are untouched.
    assert_eq!(
        app.op_get(&format!("/v1/profiles/{}", f.profile_id)).await.status(),
        StatusCode::OK
    );
    assert_eq!(
        app.op_get(&format!("/v1/documents/{}", f.document_id)).await.status(),
        StatusCode::OK
    );
}

#[tokio::test]
async fn a_deleted_job_is_gone_for_its_operator_and_its_display() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let id = app.complete_with_fake_bundle().await;
    assert_eq!(
        app.op_delete(&format!("/v1/jobs/{id}")).await.status(),
        StatusCode::NO_CONTENT
    );
    for path in [
        format!("/v1/jobs/{id}"),
        format!("/v1/jobs/{id}/evaluation"),
        format!("/v1/jobs/{id}/views"),
    ] {
        assert_eq!(app.op_get(&path).await.status(), StatusCode::NOT_FOUND, "{path}");
    }
    let zip = format!("/v1/frames/jobs/{id}/bundle.zip");
    assert_eq!(
        app.display_get(&f.display_token, &zip).await.status(),
        StatusCode::NOT_FOUND
    );
    assert!(!app.data_dir.join(format!("jobs/{id}-1")).exists());
    assert_eq!(
        app.op_delete(&format!("/v1/jobs/{id}")).await.status(),
        StatusCode::NOT_FOUND
    );
    // The document it showed stays.
    assert_eq!(
        app.op_get(&format!("/v1/documents/{}", f.document_id)).await.status(),
        StatusCode::OK
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_deleted_while_it_runs_stops_and_leaves_no_output() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let id = app.start_slow_job().await;
    assert_eq!(
        app.op_delete(&format!("/v1/jobs/{id}")).await.status(),
        StatusCode::NO_CONTENT
    );
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        let (state,): (String,) = sqlx::query_as("SELECT state FROM jobs WHERE id = $1")
            .bind(&id)
            .fetch_one(&app.state.db)
            .await
            .unwrap();
        if state != "running" {
            assert_eq!(state, "cancelled");
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the deleted job kept running");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let leftovers: Vec<_> = std::fs::read_dir(app.data_dir.join("jobs")).unwrap().collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[tokio::test]
async fn documents_and_jobs_expire_after_the_retention_period_and_profiles_do_not() {
    let app = spawn_app_with(|c| c.retention = Some(Duration::from_secs(86_400))).await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let id = app.complete_with_fake_bundle().await;
    let now = eyekey::service::store::now_ms();
    let day = 86_400_000;
    // Half a day on, nothing has expired.
    assert_eq!(
        eyekey::service::retention::purge_expired(&app.state, now + day / 2)
            .await
            .unwrap(),
        (0, 0)
    );
    assert_eq!(app.op_get(&format!("/v1/jobs/{id}")).await.status(), StatusCode::OK);
    // Two days on, the document and the job are gone, with the job's output; the profile stays.
    assert_eq!(
        eyekey::service::retention::purge_expired(&app.state, now + 2 * day)
            .await
            .unwrap(),
        (1, 1)
    );
    assert_eq!(
        app.op_get(&format!("/v1/jobs/{id}")).await.status(),
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        app.op_get(&format!("/v1/documents/{}", f.document_id)).await.status(),
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        app.op_get(&format!("/v1/profiles/{}", f.profile_id)).await.status(),
        StatusCode::OK
    );
    assert!(!app.data_dir.join(format!("jobs/{id}-1")).exists());
    let audit = expect_json(app.op_get("/v1/audit?limit=200").await, StatusCode::OK).await;
    assert!(audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e["action"] == "job.expire" && e["actor"] == "retention"));
    let expired = format!("documents/{}", f.document_id);
    assert!(audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e["action"] == "document.expire" && e["resource"] == expired.as_str()));

    let keep = spawn_app_with(|c| c.retention = None).await;
    let g = keep.fixtures().await;
    let far = eyekey::service::store::now_ms() + 3650 * day;
    assert_eq!(
        eyekey::service::retention::purge_expired(&keep.state, far)
            .await
            .unwrap(),
        (0, 0)
    );
    assert_eq!(
        keep.op_get(&format!("/v1/documents/{}", g.document_id)).await.status(),
        StatusCode::OK
    );
}

#[tokio::test]
async fn data_stored_in_clear_by_an_older_version_is_sealed_at_start_and_still_works() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let f = app.fixtures().await;
    let mut body = crate::helpers::job_body(&f);
    body["options"]["document_text"] = json!({"lines": ["PIN", "4821"], "scale": 4, "alphabet": "0123456789"});
    expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let id = app.complete_with_fake_bundle().await;
    let report = bytes_of(app.op_get(&format!("/v1/jobs/{id}/evaluation")).await).await;
    let document = crate::helpers::document_png(24, 24);

    // Turn the stored data back into what an older version wrote: plain files and no data keys.
    let doc_path = format!("documents/{}.png", f.document_id);
    std::fs::remove_file(dir.path().join(format!("documents/{}.sealed", f.document_id))).unwrap();
    std::fs::write(dir.path().join(&doc_path), &document).unwrap();
    let job = app.job_row(&id).await;
    let key = eyekey::service::sealed::job_key(&app.state.master_key, &job).unwrap();
    let plain_dir = dir.path().join(format!("jobs/{id}"));
    std::fs::rename(dir.path().join(format!("jobs/{id}-1")), &plain_dir).unwrap();
    for (path, sealed) in every_file(&plain_dir) {
        let name = path
            .strip_prefix(&format!("{}/", plain_dir.display()))
            .unwrap()
            .strip_suffix(".sealed")
            .unwrap();
        let plain = key
            .open(&sealed, &eyekey::service::sealed::job_file_aad(&id, name))
            .unwrap();
        std::fs::write(plain_dir.join(name), plain).unwrap();
        std::fs::remove_file(&path).unwrap();
    }
    let options = eyekey::service::sealed::job_options(&app.state.master_key, &job).unwrap();
    sqlx::query("UPDATE documents SET data_key = NULL, path = $1 WHERE id = $2")
        .bind(&doc_path)
        .bind(&f.document_id)
        .execute(&app.state.writer.0)
        .await
        .unwrap();
    sqlx::query("UPDATE jobs SET data_key = NULL, sealed_options = NULL, options = $1, bundle_path = $2 WHERE id = $3")
        .bind(serde_json::to_string(&options).unwrap())
        .bind(format!("jobs/{id}"))
        .bind(&id)
        .execute(&app.state.writer.0)
        .await
        .unwrap();
    app.stop().await;
    assert!(contains(
        &std::fs::read(dir.path().join(&doc_path)).unwrap(),
        &document[40..72]
    ));

    let app = spawn_app_in(dir.path(), |_| {}).await;
    assert!(!dir.path().join(&doc_path).exists(), "the plain document is gone");
    assert_nowhere_in_clear(dir.path(), "the document", &document, 32);
    for (path, bytes) in every_file(dir.path()) {
        assert!(!contains(&bytes, &report), "{path} holds the report");
    }
    for (path, bytes) in every_file(dir.path()) {
        assert!(!contains(&bytes, b"\"4821\""), "{path} holds the PIN");
    }
    // Everything still works: the report, the hint, and a job on the document.
    assert_eq!(
        bytes_of(app.op_get(&format!("/v1/jobs/{id}/evaluation")).await).await,
        report
    );
    assert_eq!(app.job(&id).await["options"]["document_text"]["lines"][1], "4821");
    expect_json(
        app.op_post("/v1/jobs", &crate::helpers::job_body(&f)).await,
        StatusCode::CREATED,
    )
    .await;
    let next = app.complete_with_fake_bundle().await;
    assert_ne!(next, id);
}

#[tokio::test]
async fn leftovers_of_a_crash_are_swept_at_start_and_live_data_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let id = app.complete_with_fake_bundle().await;
    app.stop().await;
    let stale = [
        "documents/.0b5d.sealed.part",
        "jobs/.tmp-7f3e-1/frame_0.png.sealed",
        "jobs/00000000-0000-4000-8000-000000000000-1/report.json.sealed",
    ];
    for s in stale {
        let path = dir.path().join(s);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, b"left by a crash").unwrap();
    }
    let app = spawn_app_in(dir.path(), |_| {}).await;
    for s in stale {
        let top: std::path::PathBuf = Path::new(s).components().take(2).collect();
        assert!(!dir.path().join(top).exists(), "{s} was not swept");
    }
    assert_eq!(
        app.op_get(&format!("/v1/jobs/{id}/evaluation")).await.status(),
        StatusCode::OK
    );
    assert_eq!(
        app.op_get(&format!("/v1/documents/{}", f.document_id)).await.status(),
        StatusCode::OK
    );
}

#[tokio::test]
async fn a_job_options_hint_is_sealed_and_a_request_digest_is_keyed() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let mut body = crate::helpers::job_body(&f);
    body["options"]["document_text"] = json!({"lines": ["PIN", "4821"], "scale": 4, "alphabet": "0123456789"});
    let job = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let (options, sealed, hash): (String, Vec<u8>, String) =
        sqlx::query_as("SELECT options, sealed_options, request_hash FROM jobs WHERE id = $1")
            .bind(job["id"].as_str().unwrap())
            .fetch_one(&app.state.db)
            .await
            .unwrap();
    assert!(
        !options.contains("4821") && options.contains("\"document_text\":null"),
        "{options}"
    );
    assert!(!contains(&sealed, b"4821"));
    assert_eq!(hash.len(), 64);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_job_draws_a_seed_of_its_own_kept_sealed_from_displays_and_a_given_seed_reproduces_its_frames() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    let f = app.fixtures().await;
    let body = crate::helpers::job_body(&f);
    let (a, b) = (finished(&app, &body).await, finished(&app, &body).await);
    let seed_of = |job: &Value| {
        job["options"]["seed"]
            .as_u64()
            .expect("the operator sees the job's seed")
    };
    let (seed_a, seed_b) = (seed_of(&app.job(&a).await), seed_of(&app.job(&b).await));
    assert_ne!(seed_a, seed_b, "two jobs of the same request share a seed");
    let frame = |id: String| {
        let (app, token) = (&app, f.display_token.clone());
        async move {
            bytes_of(
                app.display_get(&token, &format!("/v1/frames/jobs/{id}/files/frame_0.png"))
                    .await,
            )
            .await
        }
    };
    let frame_a = frame(a.clone()).await;
    assert_ne!(
        frame_a,
        frame(b.clone()).await,
        "two jobs of the same request gave the same frames"
    );

    // The operator's record of the encode names the seed; the job's clear options do not, nor any file at rest.
    let record = expect_json(app.op_get(&format!("/v1/jobs/{a}/encoding")).await, StatusCode::OK).await;
    assert_eq!(record["options"]["seed"].as_u64(), Some(seed_a), "{record}");
    assert!(record["solver"]["iterations"].as_u64().is_some(), "{record}");
    let row = app.job_row(&a).await;
    let clear: Value = serde_json::from_str(&row.options).unwrap();
    assert!(clear["seed"].is_null(), "the seed is stored in clear: {clear}");
    for seed in [seed_a, seed_b] {
        for (path, bytes) in every_file(&app.data_dir) {
            assert!(
                !contains(&bytes, seed.to_string().as_bytes()),
                "{path} holds a job's seed in clear"
            );
        }
    }

    // What a display receives: the frames, the mask and a manifest of the display's own fields, no option.
    let token = &f.display_token;
    let manifest = bytes_of(
        app.display_get(token, &format!("/v1/frames/jobs/{a}/files/manifest.json"))
            .await,
    )
    .await;
    let manifest: Value = serde_json::from_slice(&manifest).unwrap();
    let mut keys: Vec<&str> = manifest.as_object().unwrap().keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "barrier_mask_pixels_per_hole",
            "display",
            "files",
            "format_version",
            "frame_height",
            "frame_width",
            "n_frames"
        ]
    );
    let zip = bytes_of(app.display_get(token, &format!("/v1/frames/jobs/{a}/bundle.zip")).await).await;
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(zip)).unwrap();
    let mut names: Vec<String> = archive.file_names().map(str::to_string).collect();
    names.sort();
    assert!(
        names
            .iter()
            .all(|n| n == "manifest.json" || n == "barrier_mask.png" || n.starts_with("frame_")),
        "{names:?}"
    );
    for k in 0..archive.len() {
        let mut file = archive.by_index(k).unwrap();
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut file, &mut bytes).unwrap();
        assert!(
            !contains(&bytes, seed_a.to_string().as_bytes()),
            "{} holds the seed",
            file.name()
        );
        assert!(!contains(&bytes, b"\"seed\""), "{} names a seed", file.name());
    }
    assert_eq!(
        app.display_get(token, &format!("/v1/frames/jobs/{a}/files/encoding.json"))
            .await
            .status(),
        StatusCode::NOT_FOUND
    );

    // The same request with the first job's seed gives its frames again.
    let mut seeded = body.clone();
    seeded["options"]["seed"] = json!(seed_a);
    let c = finished(&app, &seeded).await;
    assert_eq!(frame(c).await, frame_a);
}
