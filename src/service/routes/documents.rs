//! `/v1/documents`: uploaded documents (operator only).
//!
//! Upload is the raw image as the request body with `Content-Type: image/png` or `image/jpeg` (no
//! multipart). The header is checked and the pixel count limited before any pixel is decoded; the file
//! is then fully decoded under memory limits, so truncated files, wrong types and decompression bombs
//! are refused at upload rather than when a job runs. The bytes are stored sealed under a data key of the
//! document's own ([`crate::service::sealed`]); deleting the document destroys that key, removes the file
//! and deletes every job that showed it.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{DefaultBodyLimit, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::{id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiPath, ApiQuery, ErrorBody};
use crate::service::images::{self, ImageProblem};
use crate::service::sealed;
use crate::service::state::AppState;
use crate::service::store::{self, documents::DocumentRow, to_time};

/// Routes of this resource; uploads get their own body limit (`max_document_bytes`).
pub fn router(max_document_bytes: usize) -> Router<AppState> {
    Router::new()
        .route(
            "/v1/documents",
            get(list_documents)
                .post(upload_document)
                .layer(DefaultBodyLimit::max(max_document_bytes)),
        )
        .route("/v1/documents/{id}", get(get_document).delete(delete_document))
}

/// An uploaded document's metadata.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DocumentView {
    /// Id.
    pub id: Uuid,
    /// HMAC-SHA256 of the uploaded bytes under a key only this service holds, hex: equal uploads have equal
    /// values, and nobody without the service's master key can tell what was uploaded from it (a plain
    /// hash of a PIN slip would give the PIN away).
    pub content_mac: String,
    /// `image/png` or `image/jpeg`.
    pub content_type: String,
    /// Size of the upload, bytes.
    pub bytes: i64,
    /// Width, pixels.
    pub width: i64,
    /// Height, pixels.
    pub height: i64,
    /// Upload time.
    pub created_at: DateTime<Utc>,
}

/// A page of documents.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DocumentList {
    /// Documents, newest first.
    pub items: Vec<DocumentView>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

impl From<&DocumentRow> for DocumentView {
    fn from(r: &DocumentRow) -> Self {
        Self {
            id: r.id.parse().unwrap_or_default(),
            content_mac: r.content_mac.clone(),
            content_type: r.content_type.clone(),
            bytes: r.bytes,
            width: r.width,
            height: r.height,
            created_at: to_time(r.created_at),
        }
    }
}

pub use sealed::DOCUMENT_MAC;

fn internal(e: impl Into<anyhow::Error>) -> ApiError {
    ApiError::Internal(e.into())
}

fn problem(p: ImageProblem) -> ApiError {
    match p {
        ImageProblem::UnsupportedType(_) => ApiError::UnsupportedMediaType(p.to_string()),
        ImageProblem::TooManyPixels { .. } => ApiError::TooLarge {
            field: Some("pixels".into()),
            message: p.to_string(),
        },
        _ => ApiError::Invalid {
            field: Some("body".into()),
            message: p.to_string(),
        },
    }
}

/// Upload a document.
///
/// Send the image itself as the body with `Content-Type: image/png` or `image/jpeg`. Refused: other
/// types (415), bodies over the byte limit or images over the pixel limit (413, checked from the header
/// before decoding), and files that are truncated, corrupt or not of the declared type (422).
#[utoipa::path(
    post, path = "/v1/documents", tag = "documents",
    request_body(
        description = "The image file itself",
        content(("image/png"), ("image/jpeg"))
    ),
    responses(
        (status = 201, description = "Stored", body = DocumentView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 413, description = "Too many bytes or pixels", body = ErrorBody),
        (status = 415, description = "Not PNG or JPEG", body = ErrorBody),
        (status = 422, description = "Truncated, corrupt or mislabelled image", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn upload_document(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<(StatusCode, Json<DocumentView>), ApiError> {
    let content_type = headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok());
    let format = images::format_of_content_type(content_type).map_err(problem)?;
    let bytes = body.map_err(|e| {
        if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::TooLarge {
                field: Some("body".into()),
                message: format!("the document exceeds {} bytes", state.config.limits.max_document_bytes),
            }
        } else {
            ApiError::from(e)
        }
    })?;
    if bytes.is_empty() {
        return Err(ApiError::invalid("body", "the body is empty; send the image file"));
    }
    let max_pixels = state.config.limits.max_document_pixels;
    let (header, bytes) = tokio::task::spawn_blocking(move || {
        let header = images::inspect(&bytes, format, max_pixels)?;
        images::decode(&bytes, &header)?;
        Ok::<_, ImageProblem>((header, bytes))
    })
    .await
    .map_err(|e| ApiError::Internal(e.into()))?
    .map_err(problem)?;

    let id = id_text(&Uuid::new_v4());
    let len = bytes.len() as i64;
    let (dir, master, doc_id) = (state.data_dir().clone(), state.master_key.clone(), id.clone());
    let stored = tokio::task::spawn_blocking(move || sealed::store_document(&dir, &master, &doc_id, &bytes))
        .await
        .map_err(internal)?
        .map_err(ApiError::from_io)?;
    let row = store::documents::insert(
        &state.writer,
        &store::documents::NewDocument {
            id: &id,
            content_mac: &stored.content_mac,
            content_type: header.content_type(),
            bytes: len,
            width: header.width.into(),
            height: header.height.into(),
            path: &stored.path,
            data_key: &stored.data_key,
        },
    )
    .await?;
    store::audit::record(
        &state.writer,
        &op.actor(),
        "document.upload",
        &format!("documents/{id}"),
    )
    .await?;
    Ok((StatusCode::CREATED, Json(DocumentView::from(&row))))
}

/// Read a document's metadata.
#[utoipa::path(
    get, path = "/v1/documents/{id}", tag = "documents",
    params(("id" = Uuid, Path, description = "Document id")),
    responses(
        (status = 200, description = "The document's metadata", body = DocumentView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such document", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn get_document(
    State(state): State<AppState>,
    _op: Operator<scope::Submit>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<DocumentView>, ApiError> {
    let row = store::documents::get(&state.db, &id_text(&id))
        .await?
        .ok_or(ApiError::NotFound("document"))?;
    Ok(Json(DocumentView::from(&row)))
}

/// List documents, newest first.
#[utoipa::path(
    get, path = "/v1/documents", tag = "documents",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of documents", body = DocumentList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn list_documents(
    State(state): State<AppState>,
    _op: Operator<scope::Submit>,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<DocumentList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let rows = store::documents::list(&state.db, limit, cursor.as_ref()).await?;
    Ok(Json(DocumentList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.clone())),
        items: rows.iter().map(DocumentView::from).collect(),
    }))
}

/// Delete a document, and everything that showed it.
///
/// The document's data key is destroyed and its sealed file removed; every job that showed it (as the
/// document or the decoy) is deleted with its evaluation and bundle: queued ones are cancelled, running ones
/// stopped. The database's log is checkpointed, so no copy of the key survives in it.
#[utoipa::path(
    delete, path = "/v1/documents/{id}", tag = "documents",
    params(("id" = Uuid, Path, description = "Document id")),
    responses(
        (status = 204, description = "Deleted, with the jobs that showed it"),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such document", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn delete_document(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    let id = id_text(&id);
    let left = store::documents::delete(&state.writer, store::documents::Which::One(&id), store::now_ms())
        .await?
        .ok_or(ApiError::NotFound("document"))?;
    store::audit::record(
        &state.writer,
        &op.actor(),
        "document.delete",
        &format!("documents/{id}"),
    )
    .await?;
    for job in &left.jobs {
        store::audit::record(&state.writer, &op.actor(), "job.delete", &format!("jobs/{job}")).await?;
    }
    crate::service::retention::finish_deletion(&state, &left.paths).await;
    Ok(StatusCode::NO_CONTENT)
}
