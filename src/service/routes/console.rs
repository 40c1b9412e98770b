//! `/console`: the operator console, a single page served from assets compiled into the binary (no CDN, no
//! build step). It signs in with an operator token typed into the page and kept in the tab's
//! `sessionStorage`, and talks to the same API as any other client. Every page under `/console/` is the same
//! document; the script picks the view from the path.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use crate::service::error::ApiError;
use crate::service::state::AppState;

const INDEX: &str = include_str!("../console/index.html");
const SCRIPT: &str = include_str!("../console/console.js");
const STYLE: &str = include_str!("../console/console.css");
const ICON: &str = include_str!("../console/icon.svg");

/// What the page may load and where it may connect: only this origin, no inline script, no framing.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; \
                   connect-src 'self'; form-action 'none'; frame-ancestors 'none'; base-uri 'none'";

/// Routes of the console.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/console", get(index))
        .route("/console/", get(index))
        .route("/console/assets/{name}", get(asset))
        .route("/console/{*page}", get(index))
}

fn with_headers(content_type: &'static str, body: &'static str) -> Response {
    (
        StatusCode::OK,
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CSP)),
            (header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff")),
            (header::REFERRER_POLICY, HeaderValue::from_static("no-referrer")),
            (header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY")),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        body,
    )
        .into_response()
}

async fn index() -> Response {
    with_headers("text/html; charset=utf-8", INDEX)
}

async fn asset(axum::extract::Path(name): axum::extract::Path<String>) -> Result<Response, ApiError> {
    match name.as_str() {
        "console.js" => Ok(with_headers("text/javascript; charset=utf-8", SCRIPT)),
        "console.css" => Ok(with_headers("text/css; charset=utf-8", STYLE)),
        "icon.svg" => Ok(with_headers("image/svg+xml", ICON)),
        _ => Err(ApiError::NotFound("asset")),
    }
}
