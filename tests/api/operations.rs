use reqwest::StatusCode;

use crate::helpers::{expect_json, spawn_app};

#[tokio::test]
async fn health_and_readiness_answer_without_a_token() {
    let app = spawn_app().await;
    let health = expect_json(
        app.client.get(app.url("/healthz")).send().await.unwrap(),
        StatusCode::OK,
    )
    .await;
    assert_eq!(health["status"], "ok");
    let r = app.client.get(app.url("/readyz")).send().await.unwrap();
    assert_eq!(
        r.headers()["x-request-id"].len(),
        36,
        "every response carries a request id"
    );
    let ready = expect_json(r, StatusCode::OK).await;
    let r = app
        .client
        .get(app.url("/healthz"))
        .header("x-request-id", "trace-me-42")
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.headers()["x-request-id"],
        "trace-me-42",
        "a client's request id is kept"
    );
    assert_eq!(ready["status"], "ready");
}

#[tokio::test]
async fn metrics_report_jobs_by_state_queue_depth_and_http_latency_by_route() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    app.create_job(&f).await;
    let text = app
        .client
        .get(app.url("/metrics"))
        .bearer_auth(crate::helpers::OPERATOR_TOKEN)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(text.contains("eyekey_queue_depth"), "{text}");
    let anonymous = app.client.get(app.url("/metrics")).send().await.unwrap();
    assert_eq!(
        anonymous.status(),
        reqwest::StatusCode::UNAUTHORIZED,
        "metrics are for the operator"
    );
    assert!(text.contains("eyekey_jobs{state=\"queued\"}"), "{text}");
    assert!(text.contains("eyekey_http_request_duration_seconds_bucket"), "{text}");
    assert!(
        text.contains("route=\"/v1/jobs\""),
        "latency is labelled by route template: {text}"
    );
    assert!(text.contains("route=\"/v1/profiles\""));
}

#[tokio::test]
async fn the_audit_log_cannot_be_changed() {
    let app = spawn_app().await;
    app.enrol(&crate::helpers::myope()).await;
    let update = sqlx::query("UPDATE audit_log SET actor = 'someone else'")
        .execute(&app.state.db)
        .await;
    assert!(update.unwrap_err().to_string().contains("append-only"));
    let delete = sqlx::query("DELETE FROM audit_log").execute(&app.state.db).await;
    assert!(delete.is_err());
}

#[tokio::test]
async fn the_audit_log_never_holds_profile_contents() {
    let app = spawn_app().await;
    let id = app.enrol(&crate::helpers::myope()).await;
    let audit = expect_json(app.op_get("/v1/audit").await, StatusCode::OK).await;
    let text = audit.to_string();
    assert!(text.contains(&format!("profiles/{id}")));
    assert!(!text.contains("0.123456789") && !text.contains("zernike"));
}

/// The console is served without a token, every page under `/console/` is the same document, and its
/// headers keep it to its own origin (no inline script, no framing, no referrer).
#[tokio::test]
async fn the_console_is_served_with_a_strict_content_security_policy() {
    let app = crate::helpers::spawn_app().await;
    let index = app.client.get(app.url("/console")).send().await.unwrap();
    assert_eq!(index.status(), reqwest::StatusCode::OK);
    let csp = index.headers()["content-security-policy"].to_str().unwrap().to_string();
    assert_eq!(
        csp,
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; connect-src 'self'; \
         form-action 'none'; frame-ancestors 'none'; base-uri 'none'"
    );
    assert_eq!(index.headers()["referrer-policy"], "no-referrer");
    assert_eq!(index.headers()["x-frame-options"], "DENY");
    let html = index.text().await.unwrap();
    assert!(
        html.contains("/console/assets/console.js") && !html.contains("<script>"),
        "no inline script"
    );
    let page = app
        .client
        .get(app.url("/console/jobs/0f0cd33c-2d0c-4105-8a19-f19b1241a6bf"))
        .send()
        .await
        .unwrap();
    assert_eq!(page.text().await.unwrap(), html);
    for (asset, kind) in [
        ("console.js", "text/javascript"),
        ("console.css", "text/css"),
        ("icon.svg", "image/svg+xml"),
    ] {
        let r = app
            .client
            .get(app.url(&format!("/console/assets/{asset}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), reqwest::StatusCode::OK, "{asset}");
        assert!(
            r.headers()["content-type"].to_str().unwrap().starts_with(kind),
            "{asset}"
        );
        assert_eq!(r.headers()["content-security-policy"].to_str().unwrap(), csp, "{asset}");
        assert_eq!(r.headers()["x-content-type-options"], "nosniff", "{asset}");
    }
    // A name that decodes to a path is just an unknown name: assets are compiled in, never read from disk.
    let r = app
        .client
        .get(app.url("/console/assets/..%2F..%2Fmaster.key"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), reqwest::StatusCode::NOT_FOUND);
    let r = app.client.get(app.url("/console/assets/nope.js")).send().await.unwrap();
    assert_eq!(r.status(), reqwest::StatusCode::NOT_FOUND);
}
