use reqwest::StatusCode;
use serde_json::json;

use crate::helpers::{expect_error, expect_json, spawn_app, OPERATOR_TOKEN};

const OPERATOR_GETS: &[&str] = &["/v1/profiles", "/v1/displays", "/v1/documents", "/v1/jobs", "/v1/audit"];

#[tokio::test]
async fn operator_routes_refuse_a_missing_or_wrong_token_with_401() {
    let app = spawn_app().await;
    for path in OPERATOR_GETS {
        let r = app.client.get(app.url(path)).send().await.unwrap();
        assert_eq!(r.headers().get("www-authenticate").unwrap(), "Bearer");
        expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
        let r = app
            .client
            .get(app.url(path))
            .bearer_auth("not-the-token")
            .send()
            .await
            .unwrap();
        expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
        let r = app
            .client
            .get(app.url(path))
            .header("authorization", "Basic abc")
            .send()
            .await
            .unwrap();
        expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
    }
    let r = app
        .client
        .post(app.url("/v1/profiles"))
        .json(&json!({}))
        .send()
        .await
        .unwrap();
    expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
}

#[tokio::test]
async fn a_display_token_is_forbidden_on_operator_routes() {
    let app = spawn_app().await;
    let (_, token) = app.register_display().await;
    for path in OPERATOR_GETS {
        let r = app.display_get(&token, path).await;
        expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
    }
}

#[tokio::test]
async fn frame_routes_refuse_the_operator_token_and_unknown_tokens() {
    let app = spawn_app().await;
    let r = app.display_get(OPERATOR_TOKEN, "/v1/frames/jobs").await;
    expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
    let r = app.display_get("ekd_not-a-real-token", "/v1/frames/jobs").await;
    expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
    let r = app.client.get(app.url("/v1/frames/jobs")).send().await.unwrap();
    expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
}

#[tokio::test]
async fn a_display_sees_its_own_bundle_and_another_display_gets_404() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let (_, other_token) = app.register_display().await;
    app.create_job(&f).await;
    let job_id = app.complete_with_fake_bundle().await;

    let own = expect_json(
        app.display_get(&f.display_token, "/v1/frames/jobs").await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(own["items"].as_array().unwrap().len(), 1);
    assert_eq!(own["items"][0]["id"], job_id.as_str());

    let theirs = expect_json(app.display_get(&other_token, "/v1/frames/jobs").await, StatusCode::OK).await;
    assert!(theirs["items"].as_array().unwrap().is_empty());
    for path in [
        format!("/v1/frames/jobs/{job_id}"),
        format!("/v1/frames/jobs/{job_id}/bundle.zip"),
        format!("/v1/frames/jobs/{job_id}/files/frame_0.png"),
    ] {
        let r = app.display_get(&other_token, &path).await;
        expect_error(r, StatusCode::NOT_FOUND, "not_found").await;
        let r = app.client.get(app.url(&path)).send().await.unwrap();
        expect_error(r, StatusCode::UNAUTHORIZED, "unauthorized").await;
        let r = app.display_get(&f.display_token, &path).await;
        assert_eq!(r.status(), StatusCode::OK, "{path}");
    }
}

#[tokio::test]
async fn a_display_can_fetch_bundle_files_but_never_the_report_or_views() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let job_id = app.complete_with_fake_bundle().await;
    for name in [
        "report.json",
        "views",
        "bundle.zip",
        "..",
        "..%2Freport.json",
        "views%2Ftarget.png",
    ] {
        let r = app
            .display_get(&f.display_token, &format!("/v1/frames/jobs/{job_id}/files/{name}"))
            .await;
        assert_eq!(r.status(), StatusCode::NOT_FOUND, "{name}");
    }
    let r = app
        .display_get(&f.display_token, &format!("/v1/jobs/{job_id}/evaluation"))
        .await;
    expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;
    let r = app
        .display_get(&f.display_token, &format!("/v1/profiles/{}", f.profile_id))
        .await;
    expect_error(r, StatusCode::FORBIDDEN, "forbidden").await;

    // The operator reads the report and views.
    let report = expect_json(
        app.op_get(&format!("/v1/jobs/{job_id}/evaluation")).await,
        StatusCode::OK,
    )
    .await;
    assert_eq!(report["summary"]["target_psnr_db"], 30.0);
    let views = expect_json(app.op_get(&format!("/v1/jobs/{job_id}/views")).await, StatusCode::OK).await;
    assert_eq!(views["names"], json!(["target.png"]));
    let r = app.op_get(&format!("/v1/jobs/{job_id}/views/target.png")).await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "image/png");
}

#[tokio::test]
async fn every_frame_download_is_audited_with_the_display_as_actor() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    app.create_job(&f).await;
    let job_id = app.complete_with_fake_bundle().await;
    let r = app
        .display_get(&f.display_token, &format!("/v1/frames/jobs/{job_id}/bundle.zip"))
        .await;
    assert_eq!(r.status(), StatusCode::OK);
    let r = app
        .display_get(
            &f.display_token,
            &format!("/v1/frames/jobs/{job_id}/files/manifest.json"),
        )
        .await;
    assert_eq!(r.status(), StatusCode::OK);

    let audit = expect_json(app.op_get("/v1/audit").await, StatusCode::OK).await;
    let entries: Vec<(String, String, String)> = audit["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["actor"].as_str().unwrap().into(),
                e["action"].as_str().unwrap().into(),
                e["resource"].as_str().unwrap().into(),
            )
        })
        .collect();
    let actor = format!("display:{}", f.display_id);
    assert!(
        entries.contains(&(
            actor.clone(),
            "frames.download".into(),
            format!("jobs/{job_id}/bundle.zip")
        )),
        "{entries:?}"
    );
    assert!(entries.contains(&(
        actor,
        "frames.download".into(),
        format!("jobs/{job_id}/files/manifest.json")
    )));
    for action in ["profile.enrol", "display.register", "document.upload", "job.create"] {
        assert!(
            entries.iter().any(|e| e.0 == "operator" && e.1 == action),
            "{action} not audited: {entries:?}"
        );
    }
}

/// `?resource=jobs/<id>` gives that job's entries and those under it (its frame downloads), and nothing of
/// another job, even one whose id shares the prefix's first characters; a malformed resource is a 422.
#[tokio::test]
async fn the_audit_log_filters_by_resource_and_what_lies_under_it() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let first = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let second = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let job_id = app.complete_with_fake_bundle().await;
    let other = if job_id == first { second } else { first };
    let r = app
        .display_get(&f.display_token, &format!("/v1/frames/jobs/{job_id}/bundle.zip"))
        .await;
    assert_eq!(r.status(), StatusCode::OK);
    let filtered = |resource: String| {
        let app = &app;
        async move {
            let page = expect_json(
                app.op_get(&format!("/v1/audit?resource={resource}")).await,
                StatusCode::OK,
            )
            .await;
            page["items"]
                .as_array()
                .unwrap()
                .iter()
                .map(|e| {
                    (
                        e["action"].as_str().unwrap().to_string(),
                        e["resource"].as_str().unwrap().to_string(),
                    )
                })
                .collect::<Vec<_>>()
        }
    };
    let mine = filtered(format!("jobs/{job_id}")).await;
    assert!(
        mine.contains(&("job.create".into(), format!("jobs/{job_id}"))),
        "{mine:?}"
    );
    assert!(
        mine.contains(&("frames.download".into(), format!("jobs/{job_id}/bundle.zip"))),
        "{mine:?}"
    );
    assert!(
        mine.iter()
            .all(|(_, r)| r == &format!("jobs/{job_id}") || r.starts_with(&format!("jobs/{job_id}/"))),
        "{mine:?}"
    );
    let theirs = filtered(format!("jobs/{other}")).await;
    assert_eq!(theirs, vec![("job.create".to_string(), format!("jobs/{other}"))]);
    // A prefix of an id is not the id: nothing matches.
    assert!(filtered(format!("jobs/{}", &job_id[..8])).await.is_empty());
    let all_jobs = filtered("jobs".into()).await;
    assert!(
        all_jobs.len() >= 3 && all_jobs.iter().all(|(_, r)| r.starts_with("jobs/")),
        "{all_jobs:?}"
    );
    for bad in ["Jobs/x", "jobs//x", "/jobs", "jobs/%25", "jobs/x y"] {
        let r = app.op_get(&format!("/v1/audit?resource={bad}")).await;
        let e = expect_error(r, StatusCode::UNPROCESSABLE_ENTITY, "invalid").await;
        assert_eq!(e["field"], "resource", "{bad}: {e}");
    }
}
