use reqwest::StatusCode;

use crate::helpers::{
    document_png, expect_error, expect_json, png_claiming, spawn_app, spawn_app_with, TestApp, OPERATOR_TOKEN,
};

async fn upload(app: &TestApp, content_type: &str, body: Vec<u8>) -> reqwest::Response {
    app.client
        .post(app.url("/v1/documents"))
        .bearer_auth(OPERATOR_TOKEN)
        .header("content-type", content_type)
        .body(body)
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn a_png_or_jpeg_document_is_stored_with_its_size_and_a_keyed_digest() {
    let app = spawn_app().await;
    let png = document_png(30, 20);
    let doc = expect_json(upload(&app, "image/png", png.clone()).await, StatusCode::CREATED).await;
    assert_eq!((doc["width"].as_i64(), doc["height"].as_i64()), (Some(30), Some(20)));
    assert_eq!(doc["content_type"], "image/png");
    // A keyed digest: the same upload gives the same value, and it is not the plain SHA-256 (which would
    // let anyone holding it confirm a guessed document).
    use sha2::Digest as _;
    let mac = doc["content_mac"].as_str().unwrap();
    assert_eq!(mac.len(), 64);
    assert_ne!(mac, hex::encode(sha2::Sha256::digest(&png)));
    assert_eq!(
        mac,
        app.state
            .master_key
            .digest(eyekey::service::routes::documents::DOCUMENT_MAC, &png)
    );
    let again = expect_json(upload(&app, "image/png", png.clone()).await, StatusCode::CREATED).await;
    assert_eq!(again["content_mac"], doc["content_mac"]);
    let got = expect_json(
        app.op_get(&format!("/v1/documents/{}", doc["id"].as_str().unwrap()))
            .await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(got, doc);

    let mut jpeg = Vec::new();
    image::RgbImage::from_pixel(16, 8, image::Rgb([90, 90, 90]))
        .write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .unwrap();
    let doc = expect_json(upload(&app, "image/jpeg", jpeg).await, StatusCode::CREATED).await;
    assert_eq!(doc["content_type"], "image/jpeg");
}

#[tokio::test]
async fn a_truncated_png_is_refused_as_truncated() {
    let app = spawn_app().await;
    let png = document_png(64, 64);
    let cut = png[..png.len() / 2].to_vec();
    let e = expect_error(
        upload(&app, "image/png", cut).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("truncated"), "{e}");
    let e = expect_error(
        upload(&app, "image/png", png[..20].to_vec()).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("header"), "{e}");
}

#[tokio::test]
async fn text_and_mislabelled_bodies_are_refused() {
    let app = spawn_app().await;
    let e = expect_error(
        upload(&app, "text/plain", b"hello".to_vec()).await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_media_type",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("image/png"), "{e}");
    let e = expect_error(
        upload(&app, "image/jpeg", document_png(8, 8)).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("not a JPEG"), "{e}");
    let e = expect_error(
        upload(&app, "image/png", b"plain text, not a picture".to_vec()).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("not a PNG"), "{e}");
    expect_error(
        upload(&app, "image/png", Vec::new()).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
}

#[tokio::test]
async fn a_png_claiming_ten_gigapixels_is_refused_before_decoding() {
    let app = spawn_app().await;
    let bomb = png_claiming(100_000, 100_000);
    assert!(bomb.len() < 100);
    let e = expect_error(
        upload(&app, "image/png", bomb).await,
        StatusCode::PAYLOAD_TOO_LARGE,
        "too_large",
    )
    .await;
    assert_eq!(e["field"], "pixels");
    let message = e["message"].as_str().unwrap();
    assert!(
        message.contains("100000×100000") && message.contains("limit"),
        "{message}"
    );
}

#[tokio::test]
async fn a_png_that_lies_about_its_data_is_refused() {
    let app = spawn_app().await;
    // Within the pixel limit, but its data does not decode to what the header promises.
    let e = expect_error(
        upload(&app, "image/png", png_claiming(1000, 1000)).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("could not be decoded"), "{e}");
}

#[tokio::test]
async fn a_body_over_the_byte_limit_is_refused() {
    let app = spawn_app_with(|c| c.limits.max_document_bytes = 1000).await;
    let e = expect_error(
        upload(&app, "image/png", vec![0u8; 5000]).await,
        StatusCode::PAYLOAD_TOO_LARGE,
        "too_large",
    )
    .await;
    assert!(e["message"].as_str().unwrap().contains("1000 bytes"), "{e}");
}

#[tokio::test]
async fn documents_have_their_own_byte_limit_above_the_json_one() {
    let app = spawn_app_with(|c| c.limits.max_body_bytes = 1000).await;
    // A noisy image compresses badly: well over the JSON body limit.
    let img = image::RgbImage::from_fn(64, 64, |x, y| {
        image::Rgb([(x * 37 + y * 91) as u8, (x * y) as u8, (x ^ y) as u8])
    });
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    assert!(png.len() > 1000);
    expect_json(upload(&app, "image/png", png).await, StatusCode::CREATED).await;
}

/// A document rendered from text is the PNG `eyekey example document` would draw, stored sealed like an
/// upload; characters outside the font, text that does not fit and too many pixels are refused by field.
#[tokio::test]
async fn a_document_rendered_from_text_is_the_font_drawn_image_and_bad_layouts_name_their_field() {
    let app = spawn_app_with(|c| c.limits.max_document_pixels = 100_000).await;
    let body = serde_json::json!({ "lines": ["PIN", "4821"], "width": 48, "height": 48, "scale": 2 });
    let doc = expect_json(app.op_post("/v1/documents/text", &body).await, StatusCode::CREATED).await;
    assert_eq!((doc["width"].as_i64(), doc["height"].as_i64()), (Some(48), Some(48)));
    assert_eq!(doc["content_type"], "image/png");
    let id = doc["id"].as_str().unwrap();
    let r = app.op_get(&format!("/v1/documents/{id}/image")).await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "image/png");
    assert_eq!(r.headers()["cache-control"], "no-store");
    let got = image::load_from_memory(&r.bytes().await.unwrap()).unwrap().to_rgb8();
    let expected = eyekey_core::imaging::glyphs::render_text(&["PIN", "4821"], 48, 48, 2);
    assert_eq!(got, expected);
    // An upload reads back byte for byte.
    let png = document_png(30, 20);
    let up = expect_json(upload(&app, "image/png", png.clone()).await, StatusCode::CREATED).await;
    let r = app
        .op_get(&format!("/v1/documents/{}/image", up["id"].as_str().unwrap()))
        .await;
    assert_eq!(r.bytes().await.unwrap().to_vec(), png);
    let r = app
        .op_get(&format!("/v1/documents/{}/image", uuid::Uuid::new_v4()))
        .await;
    expect_error(r, StatusCode::NOT_FOUND, "not_found").await;

    for (body, status, field, words) in [
        (
            serde_json::json!({ "lines": ["PIN €"], "width": 64, "height": 64, "scale": 1 }),
            StatusCode::UNPROCESSABLE_ENTITY,
            "lines[0]",
            "not in the font",
        ),
        (
            serde_json::json!({ "lines": [], "width": 64, "height": 64, "scale": 1 }),
            StatusCode::UNPROCESSABLE_ENTITY,
            "lines",
            "1 to 16",
        ),
        (
            serde_json::json!({ "lines": ["4821"], "width": 48, "height": 48, "scale": 3 }),
            StatusCode::UNPROCESSABLE_ENTITY,
            "scale",
            "does not fit",
        ),
        (
            serde_json::json!({ "lines": ["4821"], "width": 4, "height": 48, "scale": 1 }),
            StatusCode::UNPROCESSABLE_ENTITY,
            "width",
            "8..=4096",
        ),
        (
            serde_json::json!({ "lines": ["4821"], "width": 4000, "height": 4000, "scale": 1 }),
            StatusCode::PAYLOAD_TOO_LARGE,
            "width",
            "100000 pixels",
        ),
    ] {
        let e = expect_json(app.op_post("/v1/documents/text", &body).await, status).await;
        assert_eq!(e["error"]["field"], field, "{e}");
        assert!(e["error"]["message"].as_str().unwrap().contains(words), "{e}");
    }
    let r = app.op_get(&format!("/v1/documents/{id}/image")).await;
    assert_eq!(r.headers()["x-content-type-options"], "nosniff");
    // Every read is audited.
    let audit = expect_json(app.op_get("/v1/audit").await, StatusCode::OK).await;
    let reads = audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "document.read")
        .count();
    assert_eq!(reads, 3, "{audit}");
    // Display tokens and operator tokens without `submit` never read or render a document.
    let (_, display) = app.register_display().await;
    let r = app.display_get(&display, &format!("/v1/documents/{id}/image")).await;
    expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
    for scope in ["enrol", "read-evaluation"] {
        let made = expect_json(
            app.op_post("/v1/tokens", &serde_json::json!({ "name": scope, "scopes": [scope] }))
                .await,
            StatusCode::CREATED,
        )
        .await;
        let secret = made["secret"].as_str().unwrap();
        let r = app
            .client
            .get(app.url(&format!("/v1/documents/{id}/image")))
            .bearer_auth(secret)
            .send()
            .await
            .unwrap();
        expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
        let r = app
            .client
            .post(app.url("/v1/documents/text"))
            .bearer_auth(secret)
            .json(&body)
            .send()
            .await
            .unwrap();
        expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
    }
}

#[tokio::test]
async fn a_document_rendered_from_text_keeps_its_layout_sealed_and_jobs_on_it_are_judged_by_the_known_font_attacker() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let body = serde_json::json!({ "lines": ["PIN", "4821"], "width": 48, "height": 48, "scale": 2 });
    let doc = expect_json(app.op_post("/v1/documents/text", &body).await, StatusCode::CREATED).await;
    assert_eq!(doc["keeps_layout"], true, "{doc}");
    let id = doc["id"].as_str().unwrap();
    // The job gives no hint: it takes the document's own, its digits masked (read from the document when the job
    // runs), so the PIN is not in the job's view.
    let mut job = crate::helpers::job_body(&f);
    job["document_id"] = serde_json::json!(id);
    let created = expect_json(app.op_post("/v1/jobs", &job).await, StatusCode::CREATED).await;
    assert_eq!(
        created["options"]["document_text"],
        serde_json::json!({ "lines": ["PIN", "****"], "scale": 2, "alphabet": "0123456789" }),
        "{created}"
    );
    assert!(!created.to_string().contains("4821"), "{created}");
    // A hint the operator gives wins.
    job["options"]["document_text"] =
        serde_json::json!({ "lines": ["PIN", "48**"], "scale": 2, "alphabet": "0123456789" });
    let given = expect_json(app.op_post("/v1/jobs", &job).await, StatusCode::CREATED).await;
    assert_eq!(given["options"]["document_text"]["lines"][1], "48**");
    // An alphabet the font cannot draw is refused, naming the field.
    let bad = serde_json::json!({ "lines": ["PIN", "4821"], "width": 48, "height": 48, "scale": 2, "alphabet": "01€" });
    let e = expect_error(
        app.op_post("/v1/documents/text", &bad).await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid",
    )
    .await;
    assert_eq!(e["field"], "alphabet");
    // The layout is sealed: its text is nowhere in the clear at rest (the database included).
    let mut stack = vec![app.data_dir.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if let Ok(bytes) = std::fs::read(&path) {
                assert!(
                    !bytes.windows(6).any(|w| w == b"\"4821\""),
                    "{} holds the PIN",
                    path.display()
                );
            }
        }
    }
    // An upload keeps none, and a text with no secret character keeps none either.
    let up = expect_json(
        upload(&app, "image/png", document_png(30, 20)).await,
        StatusCode::CREATED,
    )
    .await;
    assert_eq!(up["keeps_layout"], false);
    let plain = serde_json::json!({ "lines": ["HELLO"], "width": 48, "height": 48, "scale": 1 });
    let plain = expect_json(app.op_post("/v1/documents/text", &plain).await, StatusCode::CREATED).await;
    assert_eq!(plain["keeps_layout"], false);
}
