use reqwest::StatusCode;

use crate::helpers::{expect_error, spawn_app, spawn_app_with, OPERATOR_TOKEN};

#[tokio::test]
async fn unknown_routes_and_wrong_methods_get_the_json_error_shape() {
    let app = spawn_app().await;
    let r = app.client.get(app.url("/v1/nothing-here")).send().await.unwrap();
    expect_error(r, StatusCode::NOT_FOUND, "not_found").await;
    let r = app
        .client
        .patch(app.url("/v1/profiles"))
        .bearer_auth(OPERATOR_TOKEN)
        .send()
        .await
        .unwrap();
    expect_error(r, StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed").await;
}

#[tokio::test]
async fn malformed_json_and_a_missing_content_type_are_client_errors() {
    let app = spawn_app().await;
    let r = app
        .client
        .post(app.url("/v1/profiles"))
        .bearer_auth(OPERATOR_TOKEN)
        .header("content-type", "application/json")
        .body("{not json")
        .send()
        .await
        .unwrap();
    expect_error(r, StatusCode::BAD_REQUEST, "malformed_json").await;
    let r = app
        .client
        .post(app.url("/v1/profiles"))
        .bearer_auth(OPERATOR_TOKEN)
        .body("{}")
        .send()
        .await
        .unwrap();
    expect_error(r, StatusCode::UNSUPPORTED_MEDIA_TYPE, "unsupported_media_type").await;
}

#[tokio::test]
async fn a_json_body_over_the_limit_is_refused() {
    let app = spawn_app_with(|c| c.limits.max_body_bytes = 512).await;
    let big = serde_json::json!({ "label": "x".repeat(2000), "profile": crate::helpers::myope() });
    let r = app.op_post("/v1/profiles", &big).await;
    expect_error(r, StatusCode::PAYLOAD_TOO_LARGE, "too_large").await;
}

#[tokio::test]
async fn a_malformed_id_in_the_path_is_a_client_error() {
    let app = spawn_app().await;
    let r = app.op_get("/v1/jobs/not-a-uuid").await;
    expect_error(r, StatusCode::BAD_REQUEST, "invalid_path").await;
}
