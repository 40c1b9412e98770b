//! The service's one HTTP error type and the extractors whose rejections use its JSON shape.
//!
//! Every 4xx and 5xx response body is `{"error": {"code", "message", "field"}}`. Internal errors are
//! logged with their cause and reach the client as an opaque `internal` error.

use axum::extract::rejection::{BytesRejection, JsonRejection, PathRejection, QueryRejection};
use axum::extract::{FromRequest, FromRequestParts};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

/// The body of every error response.
#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// What went wrong.
    pub error: ErrorDetail,
}

/// One error.
#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ErrorDetail {
    /// Stable machine-readable code, e.g. `invalid`, `not_found`, `unauthorized`.
    pub code: String,
    /// Human-readable explanation naming the problem.
    pub message: String,
    /// The request field at fault, when there is one (dotted path, e.g. `profile.pupil_diameter_mm`).
    pub field: Option<String>,
}

/// An error a handler returns; mapped once to a status code and the JSON shape.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The request is well-formed but its content is invalid (422).
    #[error("{message}")]
    Invalid {
        /// The field at fault.
        field: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// The request could not be parsed (400).
    #[error("{message}")]
    BadRequest {
        /// Machine-readable code.
        code: &'static str,
        /// What is wrong.
        message: String,
    },
    /// No or an unknown bearer token (401).
    #[error("a valid bearer token is required")]
    Unauthorized,
    /// A known token without the right to do this (403).
    #[error("{0}")]
    Forbidden(String),
    /// The resource does not exist, or is not visible to the caller (404).
    #[error("{0} not found")]
    NotFound(&'static str),
    /// The request conflicts with the resource's state (409).
    #[error("{message}")]
    Conflict {
        /// Machine-readable code.
        code: &'static str,
        /// What conflicts.
        message: String,
    },
    /// The body or the image is too large (413).
    #[error("{message}")]
    TooLarge {
        /// The field at fault.
        field: Option<String>,
        /// The limit exceeded.
        message: String,
    },
    /// The body's content type is not accepted (415).
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// The service cannot serve the request right now (503).
    #[error("{0}")]
    Unavailable(String),
    /// The data directory is full: nothing was stored; retry when space is freed (507).
    #[error("{0}")]
    InsufficientStorage(String),
    /// A response produced below the handlers (routing, timeouts, limits) with only a status code.
    #[error("{}", .0.canonical_reason().unwrap_or("error"))]
    Status(StatusCode),
    /// Anything unexpected: logged, and opaque to the client (500).
    #[error(transparent)]
    Internal(#[from] anyhow::Error),
}

impl ApiError {
    /// An invalid field.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            field: Some(field.into()),
            message: message.into(),
        }
    }

    /// The HTTP status of this error.
    pub fn status_code(&self) -> StatusCode {
        match self {
            Self::Invalid { .. } => StatusCode::UNPROCESSABLE_ENTITY,
            Self::BadRequest { .. } => StatusCode::BAD_REQUEST,
            Self::Unauthorized => StatusCode::UNAUTHORIZED,
            Self::Forbidden(_) => StatusCode::FORBIDDEN,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::Conflict { .. } => StatusCode::CONFLICT,
            Self::TooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            Self::UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::InsufficientStorage(_) => StatusCode::INSUFFICIENT_STORAGE,
            Self::Status(s) => *s,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    fn code(&self) -> String {
        match self {
            Self::Invalid { .. } => "invalid".into(),
            Self::BadRequest { code, .. } | Self::Conflict { code, .. } => (*code).into(),
            Self::Unauthorized => "unauthorized".into(),
            Self::Forbidden(_) => "forbidden".into(),
            Self::NotFound(_) => "not_found".into(),
            Self::TooLarge { .. } => "too_large".into(),
            Self::UnsupportedMediaType(_) => "unsupported_media_type".into(),
            Self::Unavailable(_) => "unavailable".into(),
            Self::InsufficientStorage(_) => "insufficient_storage".into(),
            Self::Status(s) => s
                .canonical_reason()
                .unwrap_or("error")
                .to_ascii_lowercase()
                .replace([' ', '-'], "_"),
            Self::Internal(_) => "internal".into(),
        }
    }

    fn field(&self) -> Option<String> {
        match self {
            Self::Invalid { field, .. } | Self::TooLarge { field, .. } => field.clone(),
            _ => None,
        }
    }
}

impl ApiError {
    /// An I/O error of storing something: a full disk (or quota) is a 507 naming the cause, a read-only
    /// data directory a 503; anything else is internal.
    pub fn from_io(e: std::io::Error) -> Self {
        match storage_problem(&e) {
            Some(problem) => problem,
            None => Self::Internal(e.into()),
        }
    }
}

/// The 507 or 503 an I/O error means for storage, if it is one of those.
fn storage_problem(e: &std::io::Error) -> Option<ApiError> {
    const ENOSPC: i32 = 28;
    const EROFS: i32 = 30;
    const EDQUOT: i32 = 122;
    match (e.kind(), e.raw_os_error()) {
        (std::io::ErrorKind::StorageFull, _) | (_, Some(ENOSPC | EDQUOT)) => Some(ApiError::InsufficientStorage(
            "the data directory is full; nothing was stored. Free space and retry".into(),
        )),
        (std::io::ErrorKind::ReadOnlyFilesystem, _) | (_, Some(EROFS)) => Some(ApiError::Unavailable(
            "the data directory is read-only; nothing was stored".into(),
        )),
        _ => None,
    }
}

/// True when a database error is SQLite's "database or disk is full" (SQLITE_FULL, 13).
pub fn is_disk_full(e: &sqlx::Error) -> bool {
    match e {
        sqlx::Error::Database(d) => {
            d.code().is_some_and(|c| c == "13" || c.starts_with("13")) || d.message().contains("disk is full")
        }
        sqlx::Error::Io(io) => storage_problem(io).is_some(),
        _ => false,
    }
}

impl From<sqlx::Error> for ApiError {
    fn from(e: sqlx::Error) -> Self {
        if is_disk_full(&e) {
            return Self::InsufficientStorage(
                "the data directory is full; nothing was stored. Free space and retry".into(),
            );
        }
        if let sqlx::Error::Database(d) = &e {
            if d.message().contains("readonly") {
                return Self::Unavailable("the data directory is read-only; nothing was stored".into());
            }
        }
        Self::Internal(e.into())
    }
}

impl ApiError {
    /// An internal error whose cause is a full or read-only disk, anywhere in its chain, becomes the 507 or
    /// 503 that says so.
    fn storage_cause(self) -> Self {
        let Self::Internal(e) = &self else { return self };
        for cause in e.chain() {
            if let Some(db) = cause.downcast_ref::<sqlx::Error>() {
                if is_disk_full(db) {
                    return Self::InsufficientStorage(
                        "the data directory is full; nothing was stored. Free space and retry".into(),
                    );
                }
            }
            if let Some(problem) = cause.downcast_ref::<std::io::Error>().and_then(storage_problem) {
                return problem;
            }
        }
        self
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let this = self.storage_cause();
        let status = this.status_code();
        let message = match &this {
            Self::Internal(e) => {
                tracing::error!(error = ?e, "internal error");
                "internal server error".to_string()
            }
            other => other.to_string(),
        };
        let body = ErrorBody {
            error: ErrorDetail {
                code: this.code(),
                message,
                field: this.field(),
            },
        };
        let mut response = (status, axum::Json(body)).into_response();
        if status == StatusCode::UNAUTHORIZED {
            response
                .headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        response
    }
}

/// Prefix axum puts before serde's message; the rest is `path: message` (serde_path_to_error).
const DESERIALIZE_PREFIX: &str = "Failed to deserialize the JSON body into the target type: ";

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> Self {
        match r {
            JsonRejection::JsonDataError(e) => {
                let text = e.body_text();
                let detail = text.strip_prefix(DESERIALIZE_PREFIX).unwrap_or(&text).to_string();
                // `profile.pupil_diameter_mm: invalid type ...` names the field; a bare message does not.
                let field = detail
                    .split_once(": ")
                    .map(|(path, _)| path)
                    .filter(|p| !p.is_empty() && !p.contains(' ') && *p != ".")
                    .map(str::to_string);
                Self::Invalid { field, message: detail }
            }
            JsonRejection::JsonSyntaxError(e) => Self::BadRequest {
                code: "malformed_json",
                message: e.body_text(),
            },
            JsonRejection::MissingJsonContentType(_) => {
                Self::UnsupportedMediaType("send the body as JSON with Content-Type: application/json".into())
            }
            JsonRejection::BytesRejection(e) => bytes_rejection(e),
            other => Self::BadRequest {
                code: "bad_request",
                message: other.body_text(),
            },
        }
    }
}

impl From<BytesRejection> for ApiError {
    fn from(r: BytesRejection) -> Self {
        bytes_rejection(r)
    }
}

fn bytes_rejection(r: BytesRejection) -> ApiError {
    if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::TooLarge {
            field: None,
            message: "the request body exceeds the size limit".into(),
        }
    } else {
        ApiError::BadRequest {
            code: "bad_request",
            message: r.body_text(),
        }
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        Self::BadRequest {
            code: "invalid_path",
            message: r.body_text(),
        }
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> Self {
        Self::BadRequest {
            code: "invalid_query",
            message: r.body_text(),
        }
    }
}

/// `axum::Json` whose rejections are [`ApiError`]s.
#[derive(Debug, Clone, Copy, Default, FromRequest)]
#[from_request(via(axum::Json), rejection(ApiError))]
pub struct ApiJson<T>(pub T);

/// `axum::extract::Path` whose rejections are [`ApiError`]s.
#[derive(Debug, FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

/// `axum::extract::Query` whose rejections are [`ApiError`]s.
#[derive(Debug, FromRequestParts)]
#[from_request(via(axum::extract::Query), rejection(ApiError))]
pub struct ApiQuery<T>(pub T);

/// Middleware: any error response produced below the handlers without a JSON body (unknown route, wrong
/// method, timeout, body limit) gets the service's error shape.
pub async fn json_error_bodies(response: Response) -> Response {
    let status = response.status();
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if (status.is_client_error() || status.is_server_error()) && !is_json {
        let mut replaced = ApiError::Status(status).into_response();
        // Keep headers such as `Allow` on 405.
        for (name, value) in response.headers() {
            if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
                replaced.headers_mut().insert(name.clone(), value.clone());
            }
        }
        return replaced;
    }
    response
}

/// Turns a panic caught in a handler into an opaque 500 (the panic is logged).
pub fn panic_response(panic: Box<dyn std::any::Any + Send + 'static>) -> Response {
    let detail = panic
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| panic.downcast_ref::<&str>().copied())
        .unwrap_or("unknown panic");
    ApiError::Internal(anyhow::anyhow!("handler panicked: {detail}")).into_response()
}
