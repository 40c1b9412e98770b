use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_error, expect_json, spawn_app, tiny_display};

#[tokio::test]
async fn a_display_token_is_shown_once_and_stored_only_as_a_hash() {
    let app = spawn_app().await;
    let r = app
        .op_post("/v1/displays", &json!({ "name": "lobby", "preset": "small" }))
        .await;
    let created = expect_json(r, StatusCode::CREATED).await;
    let id = created["display"]["id"].as_str().unwrap();
    let token = created["token"].as_str().unwrap();
    assert!(token.starts_with("ekd_"));
    assert_eq!(created["display"]["frame_width"], 120);
    assert_eq!(created["display"]["bands"], 4);

    let got = expect_json(app.op_get(&format!("/v1/displays/{id}")).await, StatusCode::OK).await;
    assert!(!got.to_string().contains(token), "the token is never shown again");
    let list = expect_json(app.op_get("/v1/displays").await, StatusCode::OK).await;
    assert!(!list.to_string().contains(token));
    let db = std::fs::read(app.data_dir.join("eyekey.db")).unwrap_or_default();
    let wal = std::fs::read(app.data_dir.join("eyekey.db-wal")).unwrap_or_default();
    for bytes in [db, wal] {
        assert!(
            !bytes.windows(token.len()).any(|w| w == token.as_bytes()),
            "the token is not stored"
        );
    }

    let r = app.display_get(token, "/v1/frames/jobs").await;
    assert_eq!(r.status(), StatusCode::OK);
}

#[tokio::test]
async fn rotating_a_token_invalidates_the_old_one() {
    let app = spawn_app().await;
    let (id, old) = app.register_display().await;
    let rotated = expect_json(
        app.op_post(&format!("/v1/displays/{id}/token"), &json!({})).await,
        StatusCode::OK,
    )
    .await;
    let new = rotated["token"].as_str().unwrap();
    assert_ne!(new, old);
    expect_error(
        app.display_get(&old, "/v1/frames/jobs").await,
        StatusCode::UNAUTHORIZED,
        "unauthorized",
    )
    .await;
    assert_eq!(app.display_get(new, "/v1/frames/jobs").await.status(), StatusCode::OK);
}

#[tokio::test]
async fn a_deleted_display_is_gone_and_its_token_stops_working() {
    let app = spawn_app().await;
    let (id, token) = app.register_display().await;
    assert_eq!(
        app.op_delete(&format!("/v1/displays/{id}")).await.status(),
        StatusCode::NO_CONTENT
    );
    expect_error(
        app.op_get(&format!("/v1/displays/{id}")).await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        app.display_get(&token, "/v1/frames/jobs").await,
        StatusCode::UNAUTHORIZED,
        "unauthorized",
    )
    .await;
}

#[tokio::test]
async fn a_bad_registration_is_refused_naming_the_field() {
    let app = spawn_app().await;
    let mut g = tiny_display();
    g.viewing_distance_mm = 5.0;
    let e = expect_error(
        app.op_post("/v1/displays", &json!({ "name": "x", "geometry": g }))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "geometry.viewing_distance_mm");

    let body = json!({ "name": "x", "preset": "small", "geometry": tiny_display() });
    let e = expect_error(
        app.op_post("/v1/displays", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "preset");
    let e = expect_error(
        app.op_post("/v1/displays", &json!({ "name": "x" })).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "geometry");
    let e = expect_error(
        app.op_post("/v1/displays", &json!({ "name": " ", "preset": "small" }))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "name");
    let e = expect_error(
        app.op_post("/v1/displays", &json!({ "name": "x", "preset": "huge" }))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "preset", "{e}");
}
