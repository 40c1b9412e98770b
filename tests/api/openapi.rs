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
    // The `parameters` variant is `allOf: [ObserverParameters, {kind}]`, and ObserverParameters forbids unknown
    // fields: it must declare `kind` itself, or no profile would match the schema the service answers with.
    let observer = &schemas["ObserverParameters"];
    assert_eq!(observer["additionalProperties"], false);
    assert_eq!(observer["properties"]["kind"]["enum"][0], "parameters");
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

/// The patterns the schema gives for names, labels and cursors accept exactly what the handlers accept on the
/// Basic Multilingual Plane: each is compiled and run against the handlers' own checks on texts at the edges
/// (every control, format and bidirectional-override character, blanks, other whitespace, ordinary and
/// non-Latin letters). The handlers also refuse the format characters beyond it (tags, U+E0001…), which a
/// pattern without the Unicode flag cannot name.
#[test]
fn the_schemas_patterns_accept_what_the_handlers_accept() {
    use eyekey::service::routes::{check_name, check_text};
    use eyekey::service::store::Cursor;
    let doc: serde_json::Value = serde_json::from_str(&document_json()).unwrap();
    let schemas = &doc["components"]["schemas"];
    let compile = |pattern: &serde_json::Value| regex::Regex::new(pattern.as_str().expect("a pattern")).unwrap();

    let mut texts: Vec<String> = vec![
        String::new(),
        " ".into(),
        "\t".into(),
        "  lobby  ".into(),
        "Terminal 3".into(),
        "Тест 終端 ☂".into(),
        "a\u{00A0}b".into(),
        "\u{2003}".into(),
        "\u{200B}\u{200B}".into(),
        "\u{FEFF}".into(),
    ];
    let special = (0u32..=0x9F)
        .filter(|c| !(0x20..0x7F).contains(c))
        .chain([
            0x00AD, 0x0600, 0x0605, 0x061C, 0x06DD, 0x070F, 0x180E, 0xFEFF, 0xFFF9, 0xFFFB,
        ])
        .chain(
            (0x200B..=0x200F)
                .chain(0x202A..=0x202E)
                .chain(0x2060..=0x2064)
                .chain(0x2066..=0x206F),
        )
        .map(|c| char::from_u32(c).unwrap());
    for c in special {
        texts.push(format!("name{c}"));
        texts.push(c.to_string());
    }
    // Around the ordinary characters next to the forbidden ranges.
    for c in [
        '\u{20}', '\u{7E}', '\u{A0}', '\u{AC}', '\u{AE}', '\u{061B}', '\u{200A}', '\u{2010}', '\u{2029}', '\u{205F}',
        '\u{2070}', '\u{FEFE}', '\u{FFFC}',
    ] {
        texts.push(format!("x{c}y"));
    }

    let label = compile(&schemas["EnrolProfile"]["properties"]["label"]["pattern"]);
    let token_name = compile(&schemas["CreateToken"]["properties"]["name"]["pattern"]);
    let variants = schemas["RegisterDisplay"]["oneOf"]
        .as_array()
        .expect("RegisterDisplay is a oneOf");
    assert_eq!(variants.len(), 2, "a preset or a geometry");
    for text in &texts {
        assert_eq!(
            label.is_match(text),
            check_text("label", text, 200).is_ok(),
            "label {text:?}"
        );
        assert_eq!(
            token_name.is_match(text),
            check_name("name", text, 100).is_ok(),
            "token name {text:?}"
        );
        for variant in variants {
            let target = variant["$ref"]
                .as_str()
                .unwrap()
                .trim_start_matches("#/components/schemas/");
            let name = compile(&schemas[target]["properties"]["name"]["pattern"]);
            assert_eq!(
                name.is_match(text),
                check_name("name", text, 200).is_ok(),
                "display name {text:?}"
            );
        }
    }

    let list = &doc["paths"]["/v1/jobs"]["get"]["parameters"];
    let cursor = list.as_array().unwrap().iter().find(|p| p["name"] == "cursor").unwrap();
    assert_eq!(cursor["schema"]["pattern"], eyekey::service::store::CURSOR_PATTERN);
    let cursor = compile(&cursor["schema"]["pattern"]);
    let issued = Cursor {
        created_at: 1_764_000_000_000,
        id: "3f1c0b8e-6d7a-4c2e-9a55-0d8f3b2e1a77".into(),
    }
    .encode();
    for text in [
        issued.as_str(),
        "0.1",
        "123456789012345678.abc",
        "1234567890123456789.abc",
        "0",
        "1.",
        ".a",
        "1.A",
        "1.a.b",
        "1.a_b",
        "-1.a",
        "1.0123456789012345678901234567890123456",
        "MTcwMHwzZjFj",
    ] {
        assert_eq!(cursor.is_match(text), Cursor::decode(text).is_some(), "cursor {text:?}");
    }
    assert!(cursor.is_match(&issued));

    let table = &schemas["SpectralSensitivity"]["oneOf"][1]["properties"];
    assert_eq!(
        table["wavelengths_nm"]["items"]["$ref"],
        "#/components/schemas/WavelengthSample"
    );
    assert_eq!(table["l"]["items"]["$ref"], "#/components/schemas/SampleValue");
    let sample = &schemas["WavelengthSample"];
    assert_eq!(
        (sample["minimum"].as_f64(), sample["maximum"].as_f64()),
        (Some(360.0), Some(850.0))
    );
    assert_eq!(schemas["SampleValue"]["minimum"].as_f64(), Some(0.0));
}
