use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_error, expect_json, myope, spawn_app};
use eyekey_core::physics::profile::VisionProfile;

#[tokio::test]
async fn a_profile_can_be_enrolled_read_listed_reenrolled_and_deleted() {
    let app = spawn_app().await;
    let r = app
        .op_post("/v1/profiles", &json!({ "label": "Ada", "profile": myope() }))
        .await;
    let created = expect_json(r, StatusCode::CREATED).await;
    let id = created["id"].as_str().unwrap().to_string();
    assert_eq!(created["version"], 1);

    let got = expect_json(app.op_get(&format!("/v1/profiles/{id}")).await, StatusCode::OK).await;
    assert_eq!(got["label"], "Ada");
    let profile: VisionProfile = serde_json::from_value(got["profile"].clone()).unwrap();
    assert_eq!(profile, myope());

    let list = expect_json(app.op_get("/v1/profiles").await, StatusCode::OK).await;
    assert_eq!(list["items"].as_array().unwrap().len(), 1);
    assert!(
        list["items"][0].get("profile").is_none(),
        "listings carry metadata only"
    );

    let mut second = myope();
    second.zernike_um[4] = -0.5;
    let r = app
        .op_put(&format!("/v1/profiles/{id}"), &json!({ "profile": second }))
        .await;
    let v2 = expect_json(r, StatusCode::OK).await;
    assert_eq!(v2["version"], 2);
    assert_eq!(v2["label"], "Ada", "omitting the label keeps it");
    let got = expect_json(app.op_get(&format!("/v1/profiles/{id}")).await, StatusCode::OK).await;
    assert_eq!(got["profile"]["zernike_um"][4], -0.5);
    let old = expect_json(
        app.op_get(&format!("/v1/profiles/{id}?version=1")).await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(old["profile"]["zernike_um"][4], 1.25, "earlier versions are kept");

    let r = app.op_delete(&format!("/v1/profiles/{id}")).await;
    assert_eq!(r.status(), StatusCode::NO_CONTENT);
    expect_error(
        app.op_get(&format!("/v1/profiles/{id}")).await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        app.op_delete(&format!("/v1/profiles/{id}")).await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    let list = expect_json(app.op_get("/v1/profiles").await, StatusCode::OK).await;
    assert!(list["items"].as_array().unwrap().is_empty());
    let versions: (i64,) = sqlx::query_as("SELECT COUNT(*) FROM profile_versions WHERE profile_id = $1")
        .bind(&id)
        .fetch_one(&app.state.db)
        .await
        .unwrap();
    assert_eq!(versions.0, 0, "deleting a profile erases its sealed versions");
}

#[tokio::test]
async fn an_invalid_profile_is_refused_naming_the_field() {
    let app = spawn_app().await;
    let mut p = myope();
    p.pupil_diameter_mm = 60.0;
    let e = expect_error(
        app.op_post("/v1/profiles", &json!({ "profile": p })).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "profile.pupil_diameter_mm");

    let mut p = myope();
    p.zernike_um[9] = 300.0;
    let e = expect_error(
        app.op_post("/v1/profiles", &json!({ "profile": p })).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "profile.zernike_um[9]");

    let body = json!({ "profile": { "pupil_diameter_mm": 6.0, "zernike_um": [], "colour": 1 } });
    let e = expect_error(
        app.op_post("/v1/profiles", &body).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("colour"), "{e}");

    let e = expect_error(
        app.op_post("/v1/profiles", &json!({ "label": "x" })).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("profile"), "{e}");
}

#[tokio::test]
async fn profiles_are_listed_newest_first_in_pages() {
    let app = spawn_app().await;
    let mut ids = Vec::new();
    for _ in 0..5 {
        ids.push(app.enrol(&myope()).await);
    }
    let mut seen = Vec::new();
    let mut cursor: Option<String> = None;
    loop {
        let path = match &cursor {
            Some(c) => format!("/v1/profiles?limit=2&cursor={c}"),
            None => "/v1/profiles?limit=2".to_string(),
        };
        let page = expect_json(app.op_get(&path).await, StatusCode::OK).await;
        for item in page["items"].as_array().unwrap() {
            seen.push(item["id"].as_str().unwrap().to_string());
        }
        match page["next_cursor"].as_str() {
            Some(c) => cursor = Some(c.to_string()),
            None => break,
        }
    }
    let mut expected = ids.clone();
    expected.sort();
    let mut got = seen.clone();
    got.sort();
    assert_eq!(got, expected, "every profile exactly once");
    let e = expect_error(
        app.op_get("/v1/profiles?limit=0").await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "limit");
    let e = expect_error(
        app.op_get("/v1/profiles?cursor=bogus").await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "cursor");
}

#[tokio::test]
async fn labels_and_names_refuse_control_and_bidirectional_override_characters() {
    let app = crate::helpers::spawn_app().await;
    for bad in ["a\u{0}b", "tab\there", "pay\u{202E}lam", "x\u{2066}y"] {
        let r = app
            .op_post(
                "/v1/profiles",
                &serde_json::json!({ "label": bad, "profile": crate::helpers::myope() }),
            )
            .await;
        let e = crate::helpers::expect_error(r, reqwest::StatusCode::UNPROCESSABLE_ENTITY, "invalid").await;
        assert_eq!(e["field"], "label", "{bad:?}");
        let r = app
            .op_post(
                "/v1/displays",
                &serde_json::json!({ "name": bad, "geometry": crate::helpers::tiny_display() }),
            )
            .await;
        let e = crate::helpers::expect_error(r, reqwest::StatusCode::UNPROCESSABLE_ENTITY, "invalid").await;
        assert_eq!(e["field"], "name", "{bad:?}");
    }
    let r = app
        .op_post(
            "/v1/profiles",
            &serde_json::json!({ "label": "Ünïcode ✓ 名前", "profile": crate::helpers::myope() }),
        )
        .await;
    assert_eq!(r.status(), reqwest::StatusCode::CREATED);
    // An Idempotency-Key is visible ASCII only.
    let f = app.fixtures().await;
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .bearer_auth(crate::helpers::OPERATOR_TOKEN)
        .header("Idempotency-Key", "a\tb")
        .json(&crate::helpers::job_body(&f))
        .send()
        .await
        .unwrap();
    let e = crate::helpers::expect_error(r, reqwest::StatusCode::UNPROCESSABLE_ENTITY, "invalid").await;
    assert_eq!(e["field"], "Idempotency-Key");
}
