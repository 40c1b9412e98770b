//! Scoped operator tokens: made once with their secret, stored hashed, denied by default, named in the
//! audit log, revocable.

use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::{expect_error, expect_json, myope, spawn_app, TestApp};

async fn make(app: &TestApp, name: &str, scopes: Value) -> (String, String) {
    let r = app
        .op_post("/v1/tokens", &json!({ "name": name, "scopes": scopes }))
        .await;
    let body = expect_json(r, StatusCode::CREATED).await;
    (
        body["token"]["id"].as_str().unwrap().to_string(),
        body["secret"].as_str().unwrap().to_string(),
    )
}

async fn post_as(app: &TestApp, token: &str, path: &str, body: &Value) -> reqwest::Response {
    app.client
        .post(app.url(path))
        .bearer_auth(token)
        .json(body)
        .send()
        .await
        .unwrap()
}

async fn get_as(app: &TestApp, token: &str, path: &str) -> reqwest::Response {
    app.client.get(app.url(path)).bearer_auth(token).send().await.unwrap()
}

#[tokio::test]
async fn a_scoped_token_does_what_its_scopes_allow_and_nothing_else() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let (_, submit) = make(&app, "terminal 7", json!(["submit"])).await;
    let (_, reader) = make(&app, "auditor", json!(["read-evaluation"])).await;
    let (_, enrol) = make(&app, "aberrometer", json!(["enrol"])).await;

    // submit: jobs yes, profiles and tokens no.
    let job = expect_json(
        post_as(&app, &submit, "/v1/jobs", &crate::helpers::job_body(&f)).await,
        StatusCode::CREATED,
    )
    .await;
    let id = job["id"].as_str().unwrap().to_string();
    let e = expect_error(
        post_as(&app, &submit, "/v1/profiles", &json!({ "profile": myope() })).await,
        StatusCode::FORBIDDEN,
        "forbidden",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("enrol"), "{e}");
    assert_eq!(
        get_as(&app, &submit, "/v1/tokens").await.status(),
        StatusCode::FORBIDDEN
    );
    assert_eq!(get_as(&app, &submit, "/v1/audit").await.status(), StatusCode::FORBIDDEN);
    assert_eq!(get_as(&app, &submit, "/metrics").await.status(), StatusCode::FORBIDDEN);
    // read-evaluation: reads jobs, creates none, reads no profile.
    assert_eq!(
        get_as(&app, &reader, &format!("/v1/jobs/{id}")).await.status(),
        StatusCode::OK
    );
    let r = post_as(&app, &reader, "/v1/jobs", &crate::helpers::job_body(&f)).await;
    assert_eq!(r.status(), StatusCode::FORBIDDEN);
    let r = get_as(&app, &reader, &format!("/v1/profiles/{}", f.profile_id)).await;
    assert_eq!(r.status(), StatusCode::FORBIDDEN);
    // enrol: profiles, and no jobs.
    let r = post_as(&app, &enrol, "/v1/profiles", &json!({ "profile": myope() })).await;
    assert_eq!(r.status(), StatusCode::CREATED);
    assert_eq!(get_as(&app, &enrol, "/v1/jobs").await.status(), StatusCode::FORBIDDEN);

    // The audit log names the token behind every action.
    let audit = expect_json(app.op_get("/v1/audit?limit=200").await, StatusCode::OK).await;
    let entries: Vec<(String, String)> = audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["actor"].as_str().unwrap().to_string(),
                e["action"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    assert!(
        entries.contains(&("token:terminal 7".into(), "job.create".into())),
        "{entries:?}"
    );
    assert!(
        entries.contains(&("token:aberrometer".into(), "profile.enrol".into())),
        "{entries:?}"
    );
    assert!(
        entries.contains(&("operator".into(), "token.create".into())),
        "{entries:?}"
    );
}

#[tokio::test]
async fn tokens_are_listed_without_secrets_stored_hashed_and_stop_working_when_revoked() {
    let app = spawn_app().await;
    let (id, secret) = make(&app, "terminal 7", json!(["submit", "submit"])).await;
    assert!(secret.starts_with("eko_") && secret.len() > 40);
    let listed = expect_json(app.op_get("/v1/tokens").await, StatusCode::OK).await;
    let text = listed.to_string();
    assert!(!text.contains(&secret), "{text}");
    assert_eq!(listed["items"][0]["scopes"], json!(["submit"]), "duplicates folded");
    let stored: Vec<(Vec<u8>,)> = sqlx::query_as("SELECT token_hash FROM tokens")
        .fetch_all(&app.state.db)
        .await
        .unwrap();
    use sha2::Digest as _;
    assert_eq!(stored[0].0, sha2::Sha256::digest(secret.as_bytes()).to_vec());
    for (path, bytes) in [("eyekey.db", "db"), ("eyekey.db-wal", "wal")] {
        let data = std::fs::read(app.data_dir.join(path)).unwrap_or_default();
        assert!(
            !data.windows(secret.len()).any(|w| w == secret.as_bytes()),
            "{bytes} holds the secret"
        );
    }
    assert_eq!(get_as(&app, &secret, "/v1/jobs").await.status(), StatusCode::OK);
    assert_eq!(
        app.op_delete(&format!("/v1/tokens/{id}")).await.status(),
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        get_as(&app, &secret, "/v1/jobs").await.status(),
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        app.op_delete(&format!("/v1/tokens/{id}")).await.status(),
        StatusCode::NOT_FOUND
    );
    // Its name is free again.
    make(&app, "terminal 7", json!(["enrol"])).await;
}

#[tokio::test]
async fn bad_token_requests_name_the_field() {
    let app = spawn_app().await;
    make(&app, "a", json!(["admin"])).await;
    let r = app
        .op_post("/v1/tokens", &json!({ "name": "a", "scopes": ["enrol"] }))
        .await;
    expect_error(r, StatusCode::CONFLICT, "token_name_taken").await;
    for (body, field) in [
        (json!({ "name": "b", "scopes": [] }), "scopes"),
        (json!({ "name": "", "scopes": ["enrol"] }), "name"),
        (json!({ "name": "x\u{202E}y", "scopes": ["enrol"] }), "name"),
        (json!({ "name": "operator", "scopes": ["enrol"] }), "name"),
    ] {
        let e = expect_error(
            app.op_post("/v1/tokens", &body).await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid",
        )
        .await;
        assert_eq!(e["field"], field, "{body}");
    }
    let r = app
        .op_post("/v1/tokens", &json!({ "name": "c", "scopes": ["root"] }))
        .await;
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
}

/// `GET /v1/me` tells any operator token its name and scopes; a display token is refused, no token is 401.
#[tokio::test]
async fn a_token_can_ask_who_it_is() {
    let app = spawn_app().await;
    let me = expect_json(app.op_get("/v1/me").await, StatusCode::OK).await;
    assert_eq!(me, json!({ "name": "operator", "scopes": ["admin"] }));
    let (_, secret) = make(&app, "auditor", json!(["read-evaluation", "enrol"])).await;
    let me = expect_json(get_as(&app, &secret, "/v1/me").await, StatusCode::OK).await;
    assert_eq!(
        me,
        json!({ "name": "auditor", "scopes": ["enrol", "read-evaluation"] }),
        "stored sorted"
    );
    let (_, display) = app.register_display().await;
    expect_error(
        get_as(&app, &display, "/v1/me").await,
        StatusCode::FORBIDDEN,
        "forbidden",
    )
    .await;
    expect_error(
        get_as(&app, "eko_unknown", "/v1/me").await,
        StatusCode::UNAUTHORIZED,
        "unauthorized",
    )
    .await;
}
