//! Admission control: a job, or a display, that cannot run is refused before anything is queued.

use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_json, job_body, spawn_app_with};
use eyekey_core::physics::display::DisplayGeometry;

/// 1000×1000 holes of 8×8 views, one band: the largest display the geometry checks allow (64 M unknowns).
fn largest() -> DisplayGeometry {
    let paper = DisplayGeometry::paper();
    DisplayGeometry {
        holes_x: 1000,
        holes_y: 1000,
        views_u: 8,
        views_v: 8,
        screen_pixel_pitch_mm: paper.hole_pitch_mm / 8.0,
        projectors: paper.projectors[..1].to_vec(),
        ..paper
    }
}

#[tokio::test]
async fn the_largest_display_registers_but_its_default_job_is_refused_for_its_time() {
    // 12 GiB: what the default gives on the 24 GiB reference machine, whatever this one has.
    let app = spawn_app_with(|c| c.max_job_memory_bytes = 12 << 30).await;
    let mut f = app.fixtures().await;
    let r = app
        .op_post("/v1/displays", &json!({ "name": "largest", "geometry": largest() }))
        .await;
    f.display_id = expect_json(r, StatusCode::CREATED).await["display"]["id"]
        .as_str()
        .unwrap()
        .to_string();
    let mut body = job_body(&f);
    body["options"] = json!({});
    let r = app.op_post("/v1/jobs", &body).await;
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
    let error: serde_json::Value = r.json().await.unwrap();
    let message = error["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("64000000 unknowns") && message.contains("1800 s"),
        "{message}"
    );
    let jobs = expect_json(app.op_get("/v1/jobs").await, StatusCode::OK).await;
    assert_eq!(jobs["items"], json!([]), "nothing queued");
}

#[tokio::test]
async fn a_display_no_job_could_run_on_is_refused_at_registration() {
    let app = spawn_app_with(|c| c.max_job_memory_bytes = 4 << 30).await;
    // Its cheapest job, the target alone for one iteration, needs 5.7 GB: the solver's vectors (4.9 GB), the
    // target's spectra (0.8 GB) and ray bundles.
    let r = app
        .op_post("/v1/displays", &json!({ "name": "largest", "geometry": largest() }))
        .await;
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
    let body: serde_json::Value = r.json().await.unwrap();
    let message = body["error"]["message"].as_str().unwrap();
    assert_eq!(body["error"]["field"], "geometry");
    assert!(
        message.contains("5457 MiB") && message.contains("64000000 unknowns") && message.contains("4096 MiB"),
        "{message}"
    );
    let listed = expect_json(app.op_get("/v1/displays").await, StatusCode::OK).await;
    assert_eq!(listed["items"], json!([]), "nothing registered");
}

#[tokio::test]
async fn a_job_over_the_memory_limit_is_refused_with_its_estimate_and_nothing_is_queued() {
    // The tiny display's job needs about 42 MiB; allow 128.
    let app = spawn_app_with(|c| c.max_job_memory_bytes = 128 << 20).await;
    let f = app.fixtures().await;
    let body = job_body(&f);
    expect_json(app.op_post("/v1/jobs", &body).await, StatusCode::CREATED).await;
    // A display 16 times as large registers (its cheapest job needs about 100 MiB, most of it the ray bundles
    // its largest pupils would sample); with 64 decoys, each at its own focus and again refocused, and the
    // defaults' near-pupil decoys likewise, its job would need about 930 MiB.
    let big = DisplayGeometry {
        holes_x: 48,
        holes_y: 48,
        ..crate::helpers::tiny_display()
    };
    let r = app
        .op_post("/v1/displays", &json!({ "name": "big", "geometry": big }))
        .await;
    let display = expect_json(r, StatusCode::CREATED).await["display"]["id"].clone();
    let mut body = job_body(&f);
    body["display_id"] = display;
    body["options"]["population_decoys"] = json!(64);
    let r = app.op_post("/v1/jobs", &body).await;
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
    let error: serde_json::Value = r.json().await.unwrap();
    let message = error["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("limits of 128 MiB") && message.contains("133 observers"),
        "{message}"
    );
    let jobs = expect_json(app.op_get("/v1/jobs").await, StatusCode::OK).await;
    assert_eq!(
        jobs["items"].as_array().unwrap().len(),
        1,
        "only the first job was queued"
    );
}
