use std::collections::HashSet;
use std::time::Duration;

use eyekey::service::store::{self, jobs::JobState};
use eyekey::service::try_execute_next_job;

use crate::helpers::{spawn_app, spawn_app_with};

const LEASE: Duration = Duration::from_millis(100);

#[tokio::test]
async fn an_expired_lease_requeues_the_job_while_attempts_remain_then_fails_it_with_the_reason() {
    let app = spawn_app_with(|c| {
        c.queue.max_attempts = 2;
        c.queue.lease = LEASE;
    })
    .await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let db = &app.state.writer;
    let t0 = store::now_ms();

    // A worker claims the job and dies (no heartbeat).
    let first = store::jobs::claim_next(db, "worker-a", LEASE, t0)
        .await
        .unwrap()
        .unwrap();
    assert_eq!((first.id.to_string(), first.attempts), (id.clone(), 1));
    assert!(
        store::jobs::claim_next(db, "worker-b", LEASE, t0 + 50)
            .await
            .unwrap()
            .is_none(),
        "the lease holds"
    );

    // After the lease, another worker gets it back.
    let second = store::jobs::claim_next(db, "worker-b", LEASE, t0 + 101)
        .await
        .unwrap()
        .unwrap();
    assert_eq!((second.id.to_string(), second.attempts), (id.clone(), 2));
    // The first worker's late result is refused: it no longer owns the job.
    let late = store::jobs::mark_ended(db, id.parse().unwrap(), 1, JobState::Failed, Some("late"))
        .await
        .unwrap();
    assert!(!late);

    // The second dies too; with no attempts left the job fails, saying why.
    let t1 = t0 + 101 + 101;
    assert!(store::jobs::claim_next(db, "worker-c", LEASE, t1)
        .await
        .unwrap()
        .is_none());
    let failed = store::jobs::fail_exhausted(db, t1).await.unwrap();
    assert_eq!(failed.len(), 1);
    let job = app.job(&id).await;
    assert_eq!(job["state"], "failed");
    let reason = job["last_error"].as_str().unwrap();
    assert!(
        reason.contains("lease expired") && reason.contains("attempt 2 of 2"),
        "{reason}"
    );
}

#[tokio::test]
async fn the_worker_step_ends_exhausted_jobs_before_claiming() {
    let app = spawn_app_with(|c| {
        c.queue.max_attempts = 1;
        c.queue.lease = LEASE;
    })
    .await;
    let f = app.fixtures().await;
    let id = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    store::jobs::claim_next(&app.state.writer, "dead-worker", LEASE, store::now_ms())
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(LEASE * 2).await;
    assert_eq!(try_execute_next_job(&app.state).await.unwrap(), None);
    assert_eq!(app.job(&id).await["state"], "failed");
}

#[tokio::test]
async fn concurrent_claims_never_take_the_same_job_twice() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    for _ in 0..3 {
        app.create_job(&f).await;
    }
    let now = store::now_ms();
    let claims = (0..10).map(|i| {
        let db = app.state.writer.clone();
        async move {
            store::jobs::claim_next(&db, &format!("w{i}"), Duration::from_secs(30), now)
                .await
                .unwrap()
        }
    });
    let claimed: Vec<_> = futures::future::join_all(claims).await.into_iter().flatten().collect();
    let ids: HashSet<_> = claimed.iter().map(|j| j.id).collect();
    assert_eq!((claimed.len(), ids.len()), (3, 3));
}

#[tokio::test]
async fn jobs_are_claimed_oldest_first() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let a = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    tokio::time::sleep(Duration::from_millis(5)).await;
    let b = app.create_job(&f).await["id"].as_str().unwrap().to_string();
    let now = store::now_ms();
    let first = store::jobs::claim_next(&app.state.writer, "w", Duration::from_secs(30), now)
        .await
        .unwrap()
        .unwrap();
    let second = store::jobs::claim_next(&app.state.writer, "w", Duration::from_secs(30), now)
        .await
        .unwrap()
        .unwrap();
    assert_eq!((first.id.to_string(), second.id.to_string()), (a, b));
}

#[tokio::test]
async fn a_job_whose_inputs_vanish_after_it_was_claimed_ends_without_retrying() {
    let app = spawn_app().await;
    let f = app.fixtures().await;
    let mut body = crate::helpers::job_body(&f);
    let observer = app.enrol(&crate::helpers::myope()).await;
    body["observer_profile_ids"] = serde_json::json!([observer]);
    let r = app.op_post("/v1/jobs", &body).await;
    let id = crate::helpers::expect_json(r, reqwest::StatusCode::CREATED).await["id"]
        .as_str()
        .unwrap()
        .to_string();
    let claimed = store::jobs::claim_next(&app.state.writer, "w", Duration::from_secs(30), store::now_ms())
        .await
        .unwrap()
        .unwrap();
    // The observer is deleted between the claim and the load: the job goes with it.
    app.op_delete(&format!("/v1/profiles/{observer}")).await;
    eyekey::service::jobs::execute_claimed(&app.state, claimed)
        .await
        .unwrap();
    let (state, attempts, error): (String, i64, Option<String>) =
        sqlx::query_as("SELECT state, attempts, last_error FROM jobs WHERE id = $1")
            .bind(&id)
            .fetch_one(&app.state.db)
            .await
            .unwrap();
    assert_eq!((state.as_str(), attempts), ("failed", 1), "{error:?}");
    assert!(error.unwrap().contains("observer profile"));
    assert_eq!(try_execute_next_job(&app.state).await.unwrap(), None, "never retried");
    let r = app.op_get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status(), reqwest::StatusCode::NOT_FOUND, "deleted with the profile");
}

#[tokio::test]
async fn an_empty_queue_gives_the_worker_nothing_to_do() {
    let app = spawn_app().await;
    assert_eq!(try_execute_next_job(&app.state).await.unwrap(), None);
}
