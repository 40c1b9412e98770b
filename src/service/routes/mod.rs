//! HTTP handlers, one module per resource, each with its own `router()`.

pub mod audit;
pub mod console;
pub mod displays;
pub mod documents;
pub mod evaluation;
pub mod frames;
pub mod health;
pub mod jobs;
pub mod metrics;
pub mod profiles;
pub mod tokens;

use axum::body::Body;
use axum::http::{header, HeaderValue};
use axum::response::Response;
use axum::Router;
use serde::Deserialize;
use uuid::Uuid;

use super::error::ApiError;
use super::sealed;
use super::state::AppState;
use super::store::jobs::JobRow;
use super::store::{Cursor, DEFAULT_PAGE, MAX_PAGE};

/// Every route of the service (without the documentation UI and middleware).
pub fn router(max_document_bytes: usize) -> Router<AppState> {
    Router::new()
        .merge(health::router())
        .merge(metrics::router())
        .merge(profiles::router())
        .merge(displays::router())
        .merge(documents::router(max_document_bytes))
        .merge(jobs::router())
        .merge(evaluation::router())
        .merge(frames::router())
        .merge(audit::router())
        .merge(tokens::router())
        .merge(console::router())
}

/// `?limit=&cursor=` of a listing.
#[derive(Debug, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PageQuery {
    /// Items per page (1–200, default 50).
    #[param(minimum = 1, maximum = 200)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page, as the service returned it: `<created_at>.<id>` of the last item
    /// seen.
    #[param(pattern = r"^[0-9]{1,18}\.[0-9a-z-]{1,36}$")]
    pub cursor: Option<String>,
}

impl PageQuery {
    /// Validated page size and cursor.
    pub fn parse(&self) -> Result<(u32, Option<Cursor>), ApiError> {
        let limit = self.limit.unwrap_or(DEFAULT_PAGE);
        if !(1..=MAX_PAGE).contains(&limit) {
            return Err(ApiError::invalid(
                "limit",
                format!("limit must be within 1..={MAX_PAGE}, got {limit}"),
            ));
        }
        let cursor = match &self.cursor {
            Some(c) => Some(Cursor::decode(c).ok_or_else(|| {
                ApiError::invalid("cursor", "a cursor is `<created_at>.<id>`, as `next_cursor` gives it")
            })?),
            None => None,
        };
        Ok((limit, cursor))
    }
}

/// The cursor of the next page, if `items` filled the page.
pub fn next_cursor<T>(items: &[T], limit: u32, key: impl Fn(&T) -> (i64, String)) -> Option<String> {
    if items.len() < limit as usize {
        return None;
    }
    items.last().map(|last| {
        let (created_at, id) = key(last);
        Cursor { created_at, id }.encode()
    })
}

/// Checks a human-readable text field (a label, a name): at most `max` characters, and no control
/// characters or bidirectional overrides, which could make a log line or a console show something other
/// than what is stored.
pub fn check_text(field: &str, value: &str, max: usize) -> Result<(), ApiError> {
    if value.chars().count() > max {
        return Err(ApiError::invalid(
            field,
            format!("{field} must be at most {max} characters"),
        ));
    }
    if let Some(c) = value.chars().find(|&c| c.is_control() || is_format(c)) {
        return Err(ApiError::invalid(
            field,
            format!(
                "{field} must not contain control, format or bidirectional-override characters (found U+{:04X})",
                c as u32
            ),
        ));
    }
    Ok(())
}

/// Checks a name (a display's, a token's): [`check_text`] on it as sent, and not blank. Returns it trimmed of
/// spaces.
pub fn check_name<'a>(field: &str, value: &'a str, max: usize) -> Result<&'a str, ApiError> {
    check_text(field, value, max)?;
    let name = value.trim();
    if name.is_empty() {
        return Err(ApiError::invalid(
            field,
            format!("{field} must be 1 to {max} characters, not blank"),
        ));
    }
    Ok(name)
}

/// Unicode format characters (category Cf): invisible, and the bidirectional overrides among them can make a log
/// line or a page show something other than what is stored; a name of zero-width spaces would look blank.
fn is_format(c: char) -> bool {
    matches!(c,
        '\u{00AD}' | '\u{0600}'..='\u{0605}' | '\u{061C}' | '\u{06DD}' | '\u{070F}' | '\u{180E}'
        | '\u{200B}'..='\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2060}'..='\u{2064}' | '\u{2066}'..='\u{206F}'
        | '\u{FEFF}' | '\u{FFF9}'..='\u{FFFB}' | '\u{110BD}' | '\u{110CD}' | '\u{13430}'..='\u{1343F}'
        | '\u{1BCA0}'..='\u{1BCA3}' | '\u{1D173}'..='\u{1D17A}' | '\u{E0001}' | '\u{E0020}'..='\u{E007F}')
}

/// The stored (hyphenated) form of an id.
pub fn id_text(id: &Uuid) -> String {
    id.hyphenated().to_string()
}

/// One of a job's sealed outputs (`name` relative to its output directory), opened and sent whole; a
/// missing file is a 404 of `what`.
pub async fn send_sealed(
    state: &AppState,
    job: &JobRow,
    name: &str,
    content_type: &'static str,
    download_name: Option<&str>,
    what: &'static str,
) -> Result<Response, ApiError> {
    let Some(dir) = &job.bundle_path else {
        return Err(ApiError::NotFound(what));
    };
    let id = job.id.to_string();
    let key = sealed::job_key(&state.master_key, job).map_err(|_| ApiError::NotFound(what))?;
    let path = format!("{dir}/{name}{}", sealed::SUFFIX);
    let plain = match sealed::open_object(&state.objects, &path, &key, &sealed::job_file_aad(&id, name)).await {
        Ok(p) => p,
        Err(sealed::OpenError::Missing) => return Err(ApiError::NotFound(what)),
        Err(sealed::OpenError::Io(e)) => return Err(ApiError::from_io(e)),
        Err(e @ sealed::OpenError::Open) => return Err(ApiError::Internal(anyhow::anyhow!("{path}: {e}"))),
    };
    let len = plain.len();
    let mut response = Response::new(Body::from(plain));
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    headers.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    if let Some(name) = download_name {
        if let Ok(v) = HeaderValue::from_str(&format!("attachment; filename=\"{name}\"")) {
            headers.insert(header::CONTENT_DISPOSITION, v);
        }
    }
    Ok(response)
}

/// The content type of a bundle or view file, by extension.
pub fn content_type_of(name: &str) -> &'static str {
    if name.ends_with(".png") {
        "image/png"
    } else if name.ends_with(".json") {
        "application/json"
    } else if name.ends_with(".zip") {
        "application/zip"
    } else {
        "application/octet-stream"
    }
}
