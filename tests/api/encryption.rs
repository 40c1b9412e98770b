use std::path::Path;

use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_json, myope, spawn_app, spawn_app_in};
use eyekey::service::{Application, Config};

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

fn database_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    ["eyekey.db", "eyekey.db-wal", "eyekey.db-shm"]
        .iter()
        .filter_map(|n| std::fs::read(dir.join(n)).ok().map(|b| (n.to_string(), b)))
        .collect()
}

#[tokio::test]
async fn the_database_holds_no_profile_coefficient_in_the_clear() {
    let app = spawn_app().await;
    let id = app.enrol(&myope()).await;
    let mut second = myope();
    second.zernike_um[8] = 0.987654321;
    let r = app
        .op_put(&format!("/v1/profiles/{id}"), &json!({ "profile": second }))
        .await;
    expect_json(r, StatusCode::OK).await;

    let files = database_bytes(&app.data_dir);
    assert!(
        files.iter().any(|(n, _)| n == "eyekey.db-wal"),
        "the database runs in WAL mode"
    );
    for (name, bytes) in &files {
        for needle in [&b"0.123456789"[..], b"0.987654321", b"zernike_um", b"pupil_diameter_mm"] {
            assert!(
                !contains(bytes, needle),
                "{name} holds {:?} in the clear",
                String::from_utf8_lossy(needle)
            );
        }
        for value in [0.123456789f64, 0.987654321] {
            assert!(
                !contains(bytes, &value.to_le_bytes()) && !contains(bytes, &value.to_be_bytes()),
                "{name} holds {value} as binary"
            );
        }
    }
    // Yet the operator reads it back.
    let got = expect_json(app.op_get(&format!("/v1/profiles/{id}")).await, StatusCode::OK).await;
    assert_eq!(got["profile"]["zernike_um"][8], 0.987654321);
}

#[tokio::test]
async fn a_ciphertext_moved_to_another_profile_does_not_open() {
    let app = spawn_app().await;
    let a = app.enrol(&myope()).await;
    let b = app.enrol(&myope()).await;
    // Swap a's sealed profile into b's row: the associated data (id, version) no longer matches.
    sqlx::query(
        "UPDATE profile_versions SET (nonce, ciphertext) =
             (SELECT nonce, ciphertext FROM profile_versions WHERE profile_id = $1) WHERE profile_id = $2",
    )
    .bind(&a)
    .bind(&b)
    .execute(&app.state.db)
    .await
    .unwrap();
    let r = app.op_get(&format!("/v1/profiles/{b}")).await;
    assert_eq!(r.status(), StatusCode::INTERNAL_SERVER_ERROR);
    let body: serde_json::Value = r.json().await.unwrap();
    assert_eq!(body["error"]["code"], "internal");
    assert_eq!(
        body["error"]["message"], "internal server error",
        "internal errors are opaque"
    );
}

#[tokio::test]
async fn with_no_configuration_secrets_are_generated_into_private_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = Config::new(dir.path().join("data"));
    config.bind = "127.0.0.1:0".parse().unwrap();
    config.workers = 0;
    let app = Application::build(config.clone()).await.unwrap();
    let port = app.port();
    assert_eq!(
        app.operator_token_file(),
        Some(dir.path().join("data").join("operator-token").as_path())
    );
    let shutdown = app.shutdown_handle();
    let server = tokio::spawn(app.run_until_stopped());

    let data = dir.path().join("data");
    for name in ["operator-token", "master.key"] {
        let path = data.join(name);
        assert!(path.exists(), "{name} is generated");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt as _;
            assert_eq!(
                std::fs::metadata(&path).unwrap().permissions().mode() & 0o777,
                0o600,
                "{name}"
            );
        }
    }
    assert!(data.join("eyekey.db").exists());
    let token = std::fs::read_to_string(data.join("operator-token"))
        .unwrap()
        .trim()
        .to_string();
    let r = reqwest::Client::new()
        .get(format!("http://127.0.0.1:{port}/v1/profiles"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK, "the generated token is the operator token");
    shutdown.shutdown();
    server.await.unwrap().unwrap();

    // A restart reuses the same secrets.
    let app = Application::build(config).await.unwrap();
    assert_eq!(
        std::fs::read_to_string(data.join("operator-token")).unwrap().trim(),
        token
    );
    drop(app);
}

#[tokio::test]
async fn a_different_master_key_is_refused_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_in(dir.path(), |_| {}).await;
    app.enrol(&myope()).await;
    app.stop().await;
    let mut config = crate::helpers::test_config(dir.path());
    config.master_key_hex = Some("11".repeat(32));
    let e = Application::build(config).await.err().expect("a wrong key is refused");
    assert!(e.to_string().contains("master key"), "{e}");
}
