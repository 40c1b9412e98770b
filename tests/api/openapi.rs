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

/// The schemas state the ranges the handlers enforce, and every operation lists the error statuses it can
/// answer, so a client generated from the document sends requests the service accepts.
#[test]
fn the_schemas_state_the_constraints_the_handlers_enforce() {
    let doc: serde_json::Value = serde_json::from_str(&document_json()).unwrap();
    let schemas = &doc["components"]["schemas"];
    let profile = &schemas["VisionProfile"]["properties"];
    assert_eq!(
        (
            profile["pupil_diameter_mm"]["minimum"].as_f64(),
            profile["pupil_diameter_mm"]["maximum"].as_f64()
        ),
        (Some(2.0), Some(9.0))
    );
    assert_eq!(profile["zernike_um"]["maxItems"], 66);
    let display = &schemas["DisplayGeometry"]["properties"];
    assert_eq!(
        (
            display["views_u"]["minimum"].as_f64(),
            display["views_u"]["maximum"].as_f64()
        ),
        (Some(1.0), Some(32.0))
    );
    let options = &schemas["EncodeOptions"]["properties"];
    assert_eq!(options["population_decoys"]["maximum"].as_f64(), Some(64.0));
    assert_eq!(options["max_iterations"]["maximum"].as_f64(), Some(20000.0));
    let list = &doc["paths"]["/v1/jobs"]["get"]["parameters"];
    let limit = list.as_array().unwrap().iter().find(|p| p["name"] == "limit").unwrap();
    assert_eq!(
        (limit["schema"]["minimum"].as_f64(), limit["schema"]["maximum"].as_f64()),
        (Some(1.0), Some(200.0))
    );
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            let responses = op["responses"].as_object().unwrap();
            for code in ["400", "403", "500", "503"] {
                assert!(responses.contains_key(code), "{method} {path} does not document {code}");
            }
            if op.get("requestBody").is_some() {
                for code in ["413", "415", "422", "507"] {
                    assert!(responses.contains_key(code), "{method} {path} does not document {code}");
                }
            }
        }
    }
}
