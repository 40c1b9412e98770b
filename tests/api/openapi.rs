use std::path::PathBuf;

use eyekey::service::openapi::document_json;

fn committed_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("openapi")
        .join("openapi.json")
}

/// Fails when `openapi/openapi.json` differs from the document generated from the code.
/// Regenerate with `EYEKEY_WRITE_OPENAPI=1 cargo test --test api openapi`.
#[test]
fn the_committed_openapi_document_matches_the_code() {
    let generated = document_json();
    let path = committed_path();
    if std::env::var_os("EYEKEY_WRITE_OPENAPI").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &generated).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "openapi/openapi.json is out of date; regenerate it with `EYEKEY_WRITE_OPENAPI=1 cargo test --test api openapi`"
    );
}

#[test]
fn every_operation_is_documented_with_a_summary_and_error_responses() {
    let doc: serde_json::Value = serde_json::from_str(&document_json()).unwrap();
    let paths = doc["paths"].as_object().unwrap();
    assert!(paths.len() >= 20, "{}", paths.len());
    for (path, item) in paths {
        for (method, op) in item.as_object().unwrap() {
            assert!(
                op["summary"].as_str().is_some_and(|s| !s.is_empty()),
                "{method} {path} has no summary"
            );
            if path.starts_with("/v1/") {
                assert!(op["responses"].get("401").is_some(), "{method} {path} documents no 401");
                assert!(op["security"].is_array(), "{method} {path} names no security scheme");
            }
        }
    }
}

#[tokio::test]
async fn the_served_document_equals_the_generated_one_and_the_docs_ui_is_served() {
    let app = crate::helpers::spawn_app().await;
    let served: serde_json::Value = app
        .client
        .get(app.url("/openapi.json"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let generated: serde_json::Value = serde_json::from_str(&document_json()).unwrap();
    assert_eq!(served, generated);
    let r = app.client.get(app.url("/docs/")).send().await.unwrap();
    assert_eq!(r.status(), reqwest::StatusCode::OK);
    assert!(
        r.text().await.unwrap().contains("swagger"),
        "Swagger UI is served from the binary"
    );
}
