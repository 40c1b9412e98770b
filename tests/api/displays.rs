use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_error, expect_json, spawn_app, tiny_display, TestApp};
use eyekey_core::physics::display::DisplayGeometry;

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
    let e = refused_geometry(&app, json!(g)).await;
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

/// The paper preset's geometry behind 1 mm lenslets, with views 3 mm apart at the pupil: 5 views of 0.2 mm
/// fill each lenslet, and M = A·s/(λ·d) = 1·3/(0.00055·500) ≈ 11 in every band.
fn resolving_lenslet_display() -> serde_json::Value {
    let mut g = serde_json::to_value(DisplayGeometry::paper()).unwrap();
    g["aperture"] = json!("lenslet");
    g["hole_pitch_mm"] = json!(1.0);
    g["hole_diameter_mm"] = json!(1.0);
    g["screen_pixel_pitch_mm"] = json!(0.2);
    g["gap_mm"] = json!(500.0 * 0.2 / 3.0);
    g["viewing_distance_mm"] = json!(500.0);
    g
}

#[tokio::test]
async fn the_dense_preset_does_not_resolve_its_views_and_says_so() {
    let app = spawn_app().await;
    let r = app
        .op_post("/v1/displays", &json!({ "name": "vault", "preset": "dense" }))
        .await;
    let display = expect_json(r, StatusCode::CREATED).await["display"].clone();
    let bands = display["resolvability"]["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 4);
    for b in bands {
        assert!(b["resolvability"].as_f64().unwrap() < 1.0, "{b}");
        assert!(b["wavelength_nm"].as_f64().unwrap() > 380.0, "{b}");
        assert!((b["view_spacing_mm"].as_f64().unwrap() - 0.75).abs() < 1e-9, "{b}");
        assert!(
            b["view_spread_mm"].as_f64().unwrap() > b["view_spacing_mm"].as_f64().unwrap(),
            "{b}"
        );
        assert!(
            b["views_resolved"]["4mm"].is_u64() && b["views_resolved"]["6mm"].is_u64(),
            "{b}"
        );
    }
    let warnings = display["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{display}");
    assert!(warnings[0].as_str().unwrap().contains("not resolved"), "{display}");

    // Get and list show the same figures, computed from the stored geometry.
    let id = display["id"].as_str().unwrap();
    let got = expect_json(app.op_get(&format!("/v1/displays/{id}")).await, StatusCode::OK).await;
    assert_eq!(got["resolvability"], display["resolvability"]);
    assert_eq!(got["warnings"], display["warnings"]);
    let list = expect_json(app.op_get("/v1/displays").await, StatusCode::OK).await;
    assert_eq!(list["items"][0]["warnings"], display["warnings"]);
}

#[tokio::test]
async fn a_lenslet_display_that_resolves_its_views_has_no_warnings() {
    let app = spawn_app().await;
    let r = app
        .op_post(
            "/v1/displays",
            &json!({ "name": "lenslets", "geometry": resolving_lenslet_display() }),
        )
        .await;
    let display = expect_json(r, StatusCode::CREATED).await["display"].clone();
    assert_eq!(display["geometry"]["aperture"], "lenslet");
    assert_eq!(display["warnings"], json!([]), "{display}");
    let bands = display["resolvability"]["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 4);
    for b in bands {
        assert!(b["resolvability"].as_f64().unwrap() >= 1.0, "{b}");
        assert!((b["view_spacing_mm"].as_f64().unwrap() - 3.0).abs() < 1e-9, "{b}");
        // 6 mm / 3 mm = 2 channels; 4 mm / 3 mm = 1.
        assert_eq!(b["views_resolved"], json!({ "4mm": 1, "6mm": 2 }), "{b}");
    }
}

#[tokio::test]
async fn an_unknown_aperture_is_refused_naming_the_field() {
    let app = spawn_app().await;
    let mut g = resolving_lenslet_display();
    g["aperture"] = json!("bogus");
    let r = app
        .op_post("/v1/displays", &json!({ "name": "x", "geometry": g }))
        .await;
    assert!(r.status().is_client_error(), "{}", r.status());
    let e = expect_error(r, StatusCode::UNPROCESSABLE_ENTITY, "invalid").await;
    assert_eq!(e["field"], "geometry.aperture", "{e}");
}

#[tokio::test]
async fn lenslets_too_small_for_their_views_are_refused_naming_the_field() {
    let app = spawn_app().await;
    let mut g = resolving_lenslet_display();
    // 5 views of 0.2 mm (1 mm) behind a 0.5 mm lenslet.
    g["hole_diameter_mm"] = json!(0.5);
    let e = refused_geometry(&app, json!(g)).await;
    assert_eq!(e["field"], "geometry.views_u", "{e}");
    assert!(e["message"].as_str().unwrap().contains("lenslet"), "{e}");
}

/// Registers `geometry` and expects it refused as invalid; returns the error body.
async fn refused_geometry(app: &TestApp, geometry: serde_json::Value) -> serde_json::Value {
    let r = app
        .op_post("/v1/displays", &json!({ "name": "x", "geometry": geometry }))
        .await;
    expect_error(r, StatusCode::UNPROCESSABLE_ENTITY, "invalid").await
}
