use std::time::Duration;

use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_error, expect_json, job_body, read_events, spawn_app, OPERATOR_TOKEN};
use eyekey::service::store;

#[tokio::test]
async fn the_same_idempotency_key_and_body_return_the_same_job() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let send = |body: serde_json::Value, key: &'static str| {
        app.client
            .post(app.url("/v1/jobs"))
            .bearer_auth(OPERATOR_TOKEN)
            .header("Idempotency-Key", key)
            .json(&body)
            .send()
    };
    let first = send(job_body(&f), "order-1").await.unwrap();
    assert_eq!(
        first.headers()["location"].to_str().unwrap().len(),
        "/v1/jobs/".len() + 36
    );
    let first = expect_json(first, StatusCode::CREATED).await;
    let again = expect_json(send(job_body(&f), "order-1").await.unwrap(), StatusCode::OK).await;
    assert_eq!(first["id"], again["id"]);

    // Spelling out a default option is the same request.
    let mut same = job_body(&f);
    same["options"]["method"] = json!("multiplex");
    let again = expect_json(send(same, "order-1").await.unwrap(), StatusCode::OK).await;
    assert_eq!(first["id"], again["id"]);

    let mut different = job_body(&f);
    different["options"]["max_iterations"] = json!(7);
    let e = expect_error(
        send(different.clone(), "order-1").await.unwrap(),
        StatusCode::CONFLICT,
        "idempotency_key_reused",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains(first["id"].as_str().unwrap()));

    let other = expect_json(send(different, "order-2").await.unwrap(), StatusCode::CREATED).await;
    assert_ne!(other["id"], first["id"]);
    let list = expect_json(app.op_get("/v1/jobs").await, StatusCode::OK).await;
    assert_eq!(list["items"].as_array().unwrap().len(), 2);
}

#[tokio::test]
async fn concurrent_requests_with_one_key_create_one_job() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let body = job_body(&f);
    let requests = (0..8).map(|_| {
        app.client
            .post(app.url("/v1/jobs"))
            .bearer_auth(OPERATOR_TOKEN)
            .header("Idempotency-Key", "burst")
            .json(&body)
            .send()
    });
    let responses = futures::future::join_all(requests).await;
    let mut ids = Vec::new();
    let mut created = 0;
    for r in responses {
        let r = r.unwrap();
        if r.status() == StatusCode::CREATED {
            created += 1;
        }
        let v: serde_json::Value = r.json().await.unwrap();
        ids.push(v["id"].as_str().unwrap().to_string());
    }
    ids.dedup();
    assert_eq!((created, ids.len()), (1, 1));
}

#[tokio::test]
async fn a_job_referring_to_missing_resources_or_with_bad_options_is_refused_naming_the_field() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let missing = "00000000-0000-4000-8000-000000000000";
    for field in ["display_id", "document_id", "profile_id", "decoy_document_id"] {
        let mut body = job_body(&f);
        body[field] = json!(missing);
        let e = expect_error(
            app.op_post("/v1/jobs", &body).await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid",
        )
        .await;
        assert_eq!(e["field"], field);
    }
    let mut body = job_body(&f);
    body["observer_profile_ids"] = json!([f.profile_id, missing]);
    let e = expect_error(
        app.op_post("/v1/jobs", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "observer_profile_ids[1]");

    let mut body = job_body(&f);
    body["options"]["max_iterations"] = json!(0);
    let e = expect_error(
        app.op_post("/v1/jobs", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "options.max_iterations");
    let mut body = job_body(&f);
    body["options"]["method"] = json!("magic");
    let e = expect_error(
        app.op_post("/v1/jobs", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "options.method", "{e}");
    let mut body = job_body(&f);
    body["display_id"] = json!("not-a-uuid");
    let e = expect_error(
        app.op_post("/v1/jobs", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "display_id", "{e}");
}

#[tokio::test]
async fn a_job_keeps_the_profile_version_it_was_created_with() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let job = app.create_job(&f).await;
    assert_eq!(job["profile_version"], 1);
    assert_eq!(job["state"], "queued");
    assert_eq!(job["options"]["max_iterations"], 5);
    assert_eq!(job["options"]["tolerance"], 1e-5, "defaults are filled in");
    assert_eq!(
        job["options"]["decoy_weight"], 0.3,
        "the display's default decoy weight is stated"
    );
    let r = app
        .op_put(
            &format!("/v1/profiles/{}", f.profile_id),
            &json!({ "profile": crate::helpers::myope() }),
        )
        .await;
    expect_json(r, StatusCode::OK).await;
    assert_eq!(app.job(job["id"].as_str().unwrap()).await["profile_version"], 1);
    assert_eq!(app.create_job(&f).await["profile_version"], 2);
}

#[tokio::test]
async fn a_job_on_the_secure_design_weighs_its_decoys_at_one_half_unless_asked_otherwise() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let r = app
        .op_post("/v1/displays", &json!({ "name": "terminal", "preset": "secure" }))
        .await;
    let secure = expect_json(r, StatusCode::CREATED).await["display"]["id"]
        .as_str()
        .unwrap()
        .to_string();
    let mut body = job_body(&f);
    body["display_id"] = json!(secure);
    let job = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    assert_eq!(job["options"]["decoy_weight"], 0.5, "{}", job["options"]);
    // As stored: the job's view reads its options back from the database.
    let stored = app.job(job["id"].as_str().unwrap()).await;
    assert_eq!(stored["options"]["decoy_weight"], 0.5);
    body["options"]["decoy_weight"] = json!(0.2);
    let asked = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    assert_eq!(asked["options"]["decoy_weight"], 0.2);
    // The tiny display of the fixtures is not the secure design.
    body["display_id"] = json!(f.display_id);
    body["options"]["decoy_weight"] = json!(null);
    let other = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    assert_eq!(other["options"]["decoy_weight"], 0.3);
}

#[tokio::test]
async fn cancelling_a_queued_job_cancels_it_at_once() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let r = app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await;
    let job = expect_json(r, StatusCode::OK).await;
    assert_eq!(job["state"], "cancelled");
    assert!(job["timings"]["finished_at"].is_string());
    // Nothing left to run.
    assert_eq!(eyekey::service::try_execute_next_job(&app.state).await.unwrap(), None);
    // Cancelling again is harmless.
    expect_json(
        app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await,
        StatusCode::OK,
    )
    .await;
}

#[tokio::test]
async fn cancelling_a_running_job_stops_it_and_it_ends_cancelled() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let claimed = store::jobs::claim_next(
        &app.state.writer,
        "test-worker",
        Duration::from_secs(30),
        store::now_ms(),
    )
    .await
    .unwrap()
    .unwrap();
    let r = app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await;
    let job = expect_json(r, StatusCode::ACCEPTED).await;
    assert_eq!(
        (job["state"].as_str(), job["cancel_requested"].as_bool()),
        (Some("running"), Some(true))
    );
    // The worker that holds the job sees the request and stops.
    eyekey::service::jobs::execute_claimed(&app.state, claimed)
        .await
        .unwrap();
    let job = app.job(&id).await;
    assert_eq!(job["state"], "cancelled");
    assert!(
        std::fs::read_dir(app.data_dir.join("jobs")).unwrap().next().is_none(),
        "no output is left behind"
    );
}

#[tokio::test]
async fn a_finished_job_cannot_be_cancelled() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let id = app.complete_with_fake_bundle().await;
    let e = expect_error(
        app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await,
        StatusCode::CONFLICT,
        "job_finished",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("succeeded"));
    let job = app.job(&id).await;
    assert_eq!(job["evaluation_summary"]["target_psnr_db"], 30.0);
    assert_eq!(job["bundle_files"].as_array().unwrap().len(), 4);
}

#[tokio::test]
async fn jobs_are_listed_with_state_and_display_filters() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let (other_display, _) = app.register_display().await;
    let a = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let b = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let mut body = job_body(&f);
    body["display_id"] = json!(other_display);
    let c = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await["id"]
        .as_str()
        .unwrap()
        .to_string();
    app.op_post(&format!("/v1/jobs/{a}/cancel"), &json!({})).await;

    let ids = |v: serde_json::Value| -> Vec<String> {
        v["items"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].as_str().unwrap().to_string())
            .collect()
    };
    let queued = ids(expect_json(app.op_get("/v1/jobs?state=queued").await, StatusCode::OK).await);
    assert_eq!(queued.len(), 2);
    assert!(queued.contains(&b) && queued.contains(&c));
    let cancelled = ids(expect_json(app.op_get("/v1/jobs?state=cancelled").await, StatusCode::OK).await);
    assert_eq!(cancelled, vec![a.clone()]);
    let for_other = ids(expect_json(
        app.op_get(&format!("/v1/jobs?display_id={other_display}")).await,
        StatusCode::OK,
    )
    .await);
    assert_eq!(for_other, vec![c]);
    let page = expect_json(app.op_get("/v1/jobs?limit=2").await, StatusCode::OK).await;
    assert!(page["next_cursor"].is_string());
    let rest = expect_json(
        app.op_get(&format!(
            "/v1/jobs?limit=2&cursor={}",
            page["next_cursor"].as_str().unwrap()
        ))
        .await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(rest["items"].as_array().unwrap().len(), 1);
    expect_error(
        app.op_get("/v1/jobs?state=sleeping").await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
}

#[tokio::test]
async fn the_event_stream_sends_the_job_then_each_change_and_ends_when_it_ends() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let stream = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/events")))
        .bearer_auth(OPERATOR_TOKEN)
        .send()
        .await
        .unwrap();
    assert_eq!(stream.status(), StatusCode::OK);
    assert!(stream.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/event-stream"));
    let reader = tokio::spawn(read_events(stream, Duration::from_secs(20), |_, v| {
        v["state"] == "cancelled"
    }));
    tokio::time::sleep(Duration::from_millis(200)).await;
    app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await;
    let events = reader.await.unwrap();
    let states: Vec<_> = events
        .iter()
        .map(|(name, v)| (name.as_str(), v["state"].as_str().unwrap()))
        .collect();
    assert_eq!(states, vec![("state", "queued"), ("state", "cancelled")]);
}

#[tokio::test]
async fn a_deleted_profile_takes_its_queued_jobs_with_it() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    app.op_delete(&format!("/v1/profiles/{}", f.profile_id)).await;
    let r = app.op_get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    let (state, error): (String, String) = sqlx::query_as("SELECT state, last_error FROM jobs WHERE id = $1")
        .bind(&id)
        .fetch_one(&app.state.db)
        .await
        .unwrap();
    assert_eq!(state, "cancelled", "never run");
    assert!(error.contains("deleted"), "{error}");
    assert_eq!(eyekey::service::try_execute_next_job(&app.state).await.unwrap(), None);
}

/// Runs the real encoder: the cancel request reaches the solver between iterations.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancelling_a_job_while_the_solver_runs_stops_it_within_moments() {
    let app = crate::helpers::spawn_app_with(|c| c.workers = 1).await;
    let id = app.start_slow_job().await;
    let r = app.op_post(&format!("/v1/jobs/{id}/cancel"), &json!({})).await;
    let job = expect_json(r, StatusCode::ACCEPTED).await;
    assert_eq!(job["cancel_requested"], true);
    let asked = std::time::Instant::now();
    let job = app.wait_for_terminal(&id, Duration::from_secs(30)).await;
    assert_eq!(job["state"], "cancelled", "{job}");
    assert!(asked.elapsed() < Duration::from_secs(10), "took {:?}", asked.elapsed());
    assert!(job["bundle_files"].is_null());
    let leftovers: Vec<_> = std::fs::read_dir(app.data_dir.join("jobs")).unwrap().collect();
    assert!(leftovers.is_empty(), "a cancelled job leaves no output");
}

#[tokio::test]
async fn a_job_for_a_display_that_does_not_resolve_its_views_is_accepted_with_a_warning() {
    let app = spawn_app().await;
    let mut f = app.fixtures().await;
    let r = app
        .op_post("/v1/displays", &json!({ "name": "vault", "preset": "dense" }))
        .await;
    let display = expect_json(r, StatusCode::CREATED).await["display"].clone();
    f.display_id = display["id"].as_str().unwrap().to_string();
    let job = app.create_job(&f).await;
    assert_eq!(job["state"], "queued");
    let warnings = job["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{job}");
    assert_eq!(warnings[0], display["warnings"][0], "the display's own warning");

    // The job view keeps saying so.
    let id = job["id"].as_str().unwrap();
    assert_eq!(app.job(id).await["warnings"], job["warnings"]);
    let list = expect_json(app.op_get("/v1/jobs").await, StatusCode::OK).await;
    assert_eq!(list["items"][0]["warnings"], job["warnings"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_uploaded_document_whose_text_is_too_small_to_judge_on_the_display_is_refused_before_it_is_queued() {
    // "4821" in eyekey's font at one pixel per dot on a 48-pixel page: 7 pixels tall, 1.75 holes on the fixtures'
    // 12-hole display, far below the 7 the legibility judge is calibrated from. Without a text hint nothing could
    // say whether the target reads it: the job is refused, naming the size and what would help, and nothing runs.
    let app = crate::helpers::spawn_app().await;
    let mut f = app.fixtures().await;
    let tiny = eyekey_core::imaging::glyphs::render_text(&["4821"], 48, 48, 1);
    let mut png = Vec::new();
    tiny.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    f.document_id = app.upload(png).await;
    let mut body = job_body(&f);
    body["options"]["ensure_target_reads"] = json!(true);
    let e = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::UNPROCESSABLE_ENTITY).await;
    assert_eq!(e["error"]["field"], "document_id", "{e}");
    let message = e["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("about 1.8 holes tall") && message.contains("POST /v1/documents/text"),
        "{message}"
    );
    let list = expect_json(app.op_get("/v1/jobs").await, StatusCode::OK).await;
    assert_eq!(list["items"].as_array().unwrap().len(), 0, "{list}");
    // The operator who accepts a target that may not read (the guard off) is not refused.
    body["options"]["ensure_target_reads"] = json!(false);
    expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_whose_target_cannot_read_its_frames_fails_with_target_cannot_read_and_delivers_nothing() {
    // A checkerboard at the finest pitch the display's retinal grid holds, on a display that does not resolve its
    // views (M = 0.30), seen by the fixtures' myope: nothing the encoder can do shows it to the target, with the
    // decoys at any weight. The job fails, once, naming the judge, how far it was and what would help; no frames
    // reach the display.
    let app = crate::helpers::spawn_app_with(|c| c.workers = 1).await;
    let mut f = app.fixtures().await;
    let checker = image::RgbImage::from_fn(24, 24, |x, y| {
        if (x / 2 + y / 2) % 2 == 0 {
            image::Rgb([20, 20, 20])
        } else {
            image::Rgb([235, 235, 235])
        }
    });
    let mut png = Vec::new();
    checker
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    f.document_id = app.upload(png).await;
    let mut body = job_body(&f);
    body["options"]["ensure_target_reads"] = json!(true);
    body["options"]["seed"] = json!(3);
    let created = expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    let id = created["id"].as_str().unwrap();
    let job = app.wait_for_terminal(id, Duration::from_secs(120)).await;
    assert_eq!(job["state"], "failed", "{job}");
    assert_eq!(job["attempts"], 1, "a target that cannot read is not retried: {job}");
    assert_eq!(job["error_code"], "target_cannot_read", "{job}");
    let error = job["last_error"].as_str().unwrap();
    assert!(
        error.starts_with(
            "target_cannot_read: the target does not read its view of the frames (no text hint: legibility"
        ) && error.contains("read from 0.80")
            && error.contains("what would help"),
        "{error}"
    );
    assert!(job["bundle_files"].is_null(), "{job}");
    let r = app
        .display_get(&f.display_token, &format!("/v1/frames/jobs/{id}/bundle.zip"))
        .await;
    assert_ne!(r.status(), StatusCode::OK);
}
