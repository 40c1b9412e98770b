//! End to end with the real encoder.

use std::io::Read as _;
use std::time::Duration;

use reqwest::StatusCode;
use serde_json::{json, Value};
use sha2::{Digest as _, Sha256};

use crate::helpers::{expect_json, job_body, read_events, spawn_app_with, TestApp, OPERATOR_TOKEN};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_whole_flow_from_enrolment_to_a_verified_bundle() {
    let app = spawn_app_with(|c| c.workers = 1).await;
    whole_flow(&app).await;
}

/// Enrolment, a job followed over server-sent events, the display's notification and download (every file
/// checked against the listing and the manifest), the evaluation and views, and the target's view
/// simulated again from the downloaded frames. `app` runs one worker.
pub async fn whole_flow(app: &TestApp) {
    let f = app.fixtures().await;
    let observer = app
        .enrol(&eyekey_core::physics::profile::VisionProfile::perfect())
        .await;
    let mut body = job_body(&f);
    body["observer_profile_ids"] = json!([observer]);
    let job = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let id = job["id"].as_str().unwrap().to_string();

    // Follow it to the end over server-sent events, and wait for the display's notification too.
    let display_events = app.display_get(&f.display_token, "/v1/frames/events").await;
    let notified = tokio::spawn(read_events(display_events, Duration::from_secs(120), |name, _| {
        name == "job_succeeded"
    }));
    let stream = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/events")))
        .bearer_auth(OPERATOR_TOKEN)
        .send()
        .await
        .unwrap();
    let events = read_events(stream, Duration::from_secs(120), |_, v| {
        matches!(v["state"].as_str(), Some("succeeded" | "failed" | "cancelled"))
    })
    .await;
    let last = &events.last().expect("events arrive").1;
    assert_eq!(last["state"], "succeeded", "{last}");
    assert_eq!(last["progress"], 1.0);
    assert!(last["timings"]["solve_seconds"].as_f64().unwrap() > 0.0);
    let note = notified.await.unwrap();
    assert_eq!(note.last().map(|(_, v)| v["id"].as_str().unwrap()), Some(id.as_str()));

    // The display downloads the bundle and checks every file against the listing and the manifest.
    let listing = expect_json(
        app.display_get(&f.display_token, &format!("/v1/frames/jobs/{id}"))
            .await,
        StatusCode::OK,
    )
    .await;
    let files = listing["files"].as_array().unwrap();
    let frames = files
        .iter()
        .filter(|f| f["name"].as_str().unwrap().starts_with("frame_"))
        .count();
    assert_eq!(
        frames,
        crate::helpers::tiny_display().n_bands(),
        "one frame per projector"
    );
    let r = app
        .display_get(&f.display_token, &format!("/v1/frames/jobs/{id}/bundle.zip"))
        .await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "application/zip");
    let zip_bytes = r.bytes().await.unwrap();
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(zip_bytes.to_vec())).unwrap();
    assert_eq!(zip.len(), files.len());
    let mut manifest_text = String::new();
    for file in files {
        let name = file["name"].as_str().unwrap();
        let mut entry = zip.by_name(name).unwrap();
        let mut bytes = Vec::new();
        entry.read_to_end(&mut bytes).unwrap();
        assert_eq!(
            hex::encode(Sha256::digest(&bytes)),
            file["sha256"].as_str().unwrap(),
            "{name}"
        );
        let single = app
            .display_get(&f.display_token, &format!("/v1/frames/jobs/{id}/files/{name}"))
            .await;
        assert_eq!(
            single.bytes().await.unwrap().as_ref(),
            bytes.as_slice(),
            "{name} alone equals its zip entry"
        );
        if name == "manifest.json" {
            manifest_text = String::from_utf8(bytes).unwrap();
        }
    }
    for file in files.iter().filter(|f| f["name"] != "manifest.json") {
        let sha = file["sha256"].as_str().unwrap();
        assert!(
            manifest_text.contains(sha),
            "the manifest records {}'s checksum",
            file["name"]
        );
    }
    {
        let mut entry = zip.by_name("frame_0.png").unwrap();
        let mut bytes = Vec::new();
        entry.read_to_end(&mut bytes).unwrap();
        let frame = image::load_from_memory(&bytes).unwrap();
        let (w, h) = crate::helpers::tiny_display().frame_size();
        assert_eq!((frame.width(), frame.height()), (w, h));
        assert!(matches!(frame.color(), image::ColorType::L16), "frames are 16-bit grey");
    }

    // The crate's own bundle reader accepts the downloaded zip (it verifies every size and checksum).
    let zip_path = app.data_dir.join("downloaded.zip");
    std::fs::write(&zip_path, &zip_bytes).unwrap();
    let (manifest, light_field) = eyekey_core::bundle::read_bundle(&zip_path).unwrap();
    assert_eq!(manifest.display, crate::helpers::tiny_display());

    // The operator reads the evaluation and the simulated views.
    let report = expect_json(app.op_get(&format!("/v1/jobs/{id}/evaluation")).await, StatusCode::OK).await;
    assert!(report.is_object());
    let views = expect_json(app.op_get(&format!("/v1/jobs/{id}/views")).await, StatusCode::OK).await;
    let names = views["names"].as_array().unwrap();
    assert!(!names.is_empty());
    let r = app
        .op_get(&format!("/v1/jobs/{id}/views/{}", names[0].as_str().unwrap()))
        .await;
    assert_eq!(r.status(), StatusCode::OK);

    // The target's view simulated from the downloaded bundle scores as the job's own evaluation says.
    // Same observer as the evaluation (its transport seed: the job's seed + 20000, xor 0xE7A1); the only
    // difference is the frames' 16-bit quantisation.
    let options: eyekey_core::encoding::pipeline::EncodeOptions =
        serde_json::from_value(last["options"].clone()).unwrap();
    let transport = eyekey_core::physics::transport::TransportOptions {
        sub_rays: options.sub_rays,
        seed: options.seed.expect("the job states its seed").wrapping_add(20_000) ^ 0xE7A1,
        ..Default::default()
    };
    let observer = eyekey_core::physics::observer::Observer::new(
        &manifest.display,
        &crate::helpers::myope(),
        eyekey_core::physics::transport::EyePosition::default(),
        &transport,
        options.optics,
        &eyekey_core::physics::transport::TransportCache::disabled(),
    )
    .unwrap();
    let grid = observer.grid();
    let document = image::load_from_memory(&crate::helpers::document_png(24, 24))
        .unwrap()
        .to_rgb8();
    let reference = eyekey_core::evaluation::Reference::new(
        &document,
        grid.width,
        grid.height,
        eyekey_core::encoding::pipeline::OBJECTIVE_LEVEL,
        report["threshold"].as_f64().unwrap(),
    );
    let (score, _) = reference.score_observer("target", &observer, &light_field);
    let reported = &report["target"];
    assert!(
        (score.legibility - reported["legibility"].as_f64().unwrap()).abs() < 1e-3,
        "{score:?} vs {reported}"
    );
    assert!(
        (score.psnr_db - reported["psnr_db"].as_f64().unwrap()).abs() < 0.05,
        "{score:?} vs {reported}"
    );
    // The report holds the target to the target's bar.
    let reading = reference.target_reading(&score, 0.0);
    assert_eq!(reading.reads, reported["readable"].as_bool().unwrap());
    assert_eq!(reading.reads, report["target_reading"]["reads"].as_bool().unwrap());
    // The fixtures' document is a bar 8 of 24 pixels tall: 4 holes on the 12-hole display, below the 7 the
    // legibility judge is calibrated from, so no judge can say the target reads it (the job was asked without
    // the guard, `ensure_target_reads: false`).
    assert_eq!(report["target_reading"]["judge"], "unknown");
    assert_eq!(report["target_reading"]["reads"], false);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_jobs_submitted_at_once_all_finish() {
    let app = spawn_app_with(|c| c.workers = 2).await;
    let f = app.fixtures().await;
    // The queue is under test here, not the physics: the geometric model keeps 50 solves short.
    let mut body = job_body(&f);
    body["options"]["optics"] = serde_json::json!("geometric");
    let requests = (0..50).map(|_| {
        app.client
            .post(app.url("/v1/jobs"))
            .bearer_auth(OPERATOR_TOKEN)
            .json(&body)
            .send()
    });
    let mut ids = Vec::new();
    for r in futures::future::join_all(requests).await {
        ids.push(
            expect_json(r.unwrap(), StatusCode::CREATED).await["id"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    for id in &ids {
        let job = app.wait_for_terminal(id, Duration::from_secs(150)).await;
        assert_eq!(job["state"], "succeeded", "{job}");
        assert_eq!(job["attempts"], 1);
    }
    let metrics = app
        .client
        .get(app.url("/metrics"))
        .bearer_auth(crate::helpers::OPERATOR_TOKEN)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(metrics.contains("eyekey_solve_duration_seconds_bucket"), "{metrics}");
}

/// The walkthrough's job (`examples/walkthrough.sh`): the `lenslet` preset, the example target and representative
/// observer, the uploaded PIN slip (no text hint), default options but for a fixed seed. The job succeeds only if
/// its target reads, by the reads bar of legibility; the evaluation says it reads, and the known-font attacker,
/// told the slip's text, reads the target's view of the downloaded frames too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_walkthroughs_job_gives_frames_its_target_reads() {
    let app = crate::helpers::spawn_app_with(|c| c.workers = 1).await;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let profile = |name: &str| -> Value {
        serde_json::from_slice(&std::fs::read(root.join("examples/profiles").join(name)).unwrap()).unwrap()
    };
    let enrol = |label: &str, p: Value| {
        let app = &app;
        let body = json!({ "label": label, "profile": p });
        async move { expect_json(app.op_post("/v1/profiles", &body).await, StatusCode::CREATED).await["id"].clone() }
    };
    let target = enrol("target", profile("target.json")).await;
    let representative = enrol("representative", profile("representative.json")).await;
    let display = expect_json(
        app.op_post("/v1/displays", &json!({ "name": "walkthrough", "preset": "lenslet" }))
            .await,
        StatusCode::CREATED,
    )
    .await;
    let slip = std::fs::read(root.join("examples/documents/pin_slip.png")).unwrap();
    let document = app.upload(slip.clone()).await;
    let body = json!({
        "display_id": display["display"]["id"], "document_id": document, "profile_id": target,
        "observer_profile_ids": [representative], "options": { "evaluation_population": 5, "seed": 1 },
    });
    let id = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await["id"]
        .as_str()
        .unwrap()
        .to_string();
    let job = app.wait_for_terminal(&id, Duration::from_secs(300)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let report = expect_json(app.op_get(&format!("/v1/jobs/{id}/evaluation")).await, StatusCode::OK).await;
    let reading = &report["target_reading"];
    assert_eq!(
        (&reading["judge"], &reading["reads"]),
        (&json!("legibility"), &json!(true)),
        "{reading}"
    );
    assert!(reading["score"].as_f64().unwrap() >= eyekey_core::evaluation::READS_THRESHOLD);

    // The known-font attacker, told the slip's text, reads what the target sees of the frames the display gets.
    let token = display["token"].as_str().unwrap();
    let r = app
        .display_get(token, &format!("/v1/frames/jobs/{id}/bundle.zip"))
        .await;
    assert_eq!(r.status(), StatusCode::OK);
    let zip_path = app.data_dir.join("walkthrough.zip");
    std::fs::write(&zip_path, r.bytes().await.unwrap()).unwrap();
    let (manifest, light_field) = eyekey_core::bundle::read_bundle(&zip_path).unwrap();
    let document = image::load_from_memory(&slip).unwrap().to_rgb8();
    let hint = eyekey_core::evaluation::DocumentText {
        lines: vec!["PIN".into(), "****".into()],
        scale: 7,
        alphabet: "0123456789".into(),
    }
    .resolve(&document)
    .expect("the example slip is drawn in eyekey's font at 7 px per dot (examples/README.md)");
    let me: eyekey_core::physics::profile::VisionProfile = serde_json::from_value(profile("target.json")).unwrap();
    let observer = eyekey_core::physics::observer::Observer::new(
        &manifest.display,
        &me,
        eyekey_core::physics::transport::EyePosition::default(),
        &eyekey_core::physics::transport::TransportOptions::default(),
        eyekey_core::physics::observer::Optics::Wave,
        &eyekey_core::physics::transport::TransportCache::disabled(),
    )
    .unwrap();
    let grid = observer.grid();
    let attacker = eyekey_core::evaluation::KnownFontAttacker::new(
        &hint,
        document.width(),
        document.height(),
        grid.width,
        grid.height,
    )
    .unwrap();
    let read = attacker.read(&eyekey_core::evaluation::luminance(&observer.view(&light_field)));
    assert!(read.correct, "the target's view of the delivered frames reads {read:?}");
}
