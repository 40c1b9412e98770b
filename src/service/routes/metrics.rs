//! Prometheus metrics, for the operator token only (a scraper is given it as a bearer token).
//!
//! - `eyekey_jobs{state}` and `eyekey_queue_depth`: gauges read from the database at scrape time;
//! - `eyekey_solve_duration_seconds{outcome}`: histogram of solver wall time per attempt;
//! - `eyekey_jobs_finished_total{state}`: counter of jobs reaching a terminal state;
//! - `eyekey_http_request_duration_seconds{method,route,status}`: histogram of HTTP latency by route;
//! - `eyekey_transport_cache_{hits,misses,bytes}`: the transport-operator cache.

use std::sync::OnceLock;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::http::{header, HeaderValue};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

use crate::service::error::ApiError;
use crate::service::state::AppState;
use crate::service::store;

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new().route("/metrics", get(scrape))
}

/// The process-wide Prometheus recorder (metrics recorders are global, so every `Application` in a
/// process shares it).
pub fn recorder() -> PrometheusHandle {
    static HANDLE: OnceLock<PrometheusHandle> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let builder = PrometheusBuilder::new()
                .set_buckets_for_metric(
                    Matcher::Full("eyekey_http_request_duration_seconds".into()),
                    &[
                        0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
                    ],
                )
                .and_then(|b| {
                    b.set_buckets_for_metric(
                        Matcher::Full("eyekey_solve_duration_seconds".into()),
                        &[0.1, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0],
                    )
                })
                .unwrap_or_else(|_| PrometheusBuilder::new());
            let recorder = builder.build_recorder();
            let handle = recorder.handle();
            if metrics::set_global_recorder(recorder).is_err() {
                tracing::warn!("another metrics recorder is installed; /metrics shows only the job gauges");
            }
            handle
        })
        .clone()
}

/// Prometheus text exposition.
#[utoipa::path(
    get, path = "/metrics", tag = "operations",
    responses(
        (status = 200, description = "Prometheus text format", content_type = "text/plain", body = String),
        (status = 401, description = "No or unknown token", body = crate::service::error::ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn scrape(
    State(state): State<AppState>,
    _: crate::service::auth::Operator<crate::service::auth::scope::Admin>,
) -> Result<Response, ApiError> {
    let counts = store::jobs::count_by_state(&state.db).await?;
    for (s, n) in &counts {
        metrics::gauge!("eyekey_jobs", "state" => s.as_str()).set(*n as f64);
    }
    let queued = counts
        .iter()
        .find(|(s, _)| *s == store::jobs::JobState::Queued)
        .map_or(0, |(_, n)| *n);
    metrics::gauge!("eyekey_queue_depth").set(queued as f64);
    let (hits, misses, bytes) = state.transport_cache.stats();
    metrics::gauge!("eyekey_transport_cache_hits").set(hits as f64);
    metrics::gauge!("eyekey_transport_cache_misses").set(misses as f64);
    metrics::gauge!("eyekey_transport_cache_bytes").set(bytes as f64);
    state.metrics.run_upkeep();
    let mut response = state.metrics.render().into_response();
    response.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
    );
    Ok(response)
}

/// Middleware: records each request's latency under its route template.
pub async fn track_http(request: Request, next: Next) -> Response {
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map(|m| m.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    let method = request.method().as_str().to_string();
    let start = Instant::now();
    let response = next.run(request).await;
    metrics::histogram!(
        "eyekey_http_request_duration_seconds",
        "method" => method,
        "route" => route,
        "status" => response.status().as_u16().to_string()
    )
    .record(start.elapsed().as_secs_f64());
    response
}
