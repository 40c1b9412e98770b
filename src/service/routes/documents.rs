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
use axum::response::IntoResponse as _;
use axum::routing::get;
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::{id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator};
use crate::service::error::{ApiError, ApiJson, ApiPath, ApiQuery, ErrorBody};
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
        .route("/v1/documents/text", axum::routing::post(render_document))
        .route("/v1/documents/{id}", get(get_document).delete(delete_document))
        .route("/v1/documents/{id}/image", get(get_document_image))
}

/// Body of a rendered document: lines of text drawn in eyekey's 5×7 font, black on white, centred (what
/// `eyekey example document` draws). The document keeps its layout (lines, scale, secret alphabet), sealed with it:
/// jobs on it are judged by the known-font attacker without `options.document_text`.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RenderDocument {
    /// 1–16 lines of at most 64 characters: digits, letters (drawn in upper case), space and `: - . , #`.
    #[schema(min_items = 1, max_items = 16, value_type = Vec<TextLine>)]
    pub lines: Vec<String>,
    /// Width, pixels (8–4096).
    #[schema(minimum = 8, maximum = 4096)]
    pub width: u32,
    /// Height, pixels (8–4096).
    #[schema(minimum = 8, maximum = 4096)]
    pub height: u32,
    /// Pixels per font dot (1–64); a character takes 6·scale × 9·scale pixels, and the text must fit.
    #[schema(minimum = 1, maximum = 64)]
    pub scale: u32,
    /// The secret characters (default the digits): the known-font attacker must tell these apart; the text's
    /// other characters (a label such as "PIN") are taken as known. A text with none keeps no layout.
    #[serde(default)]
    #[schema(max_length = 64)]
    pub alphabet: Option<String>,
}

/// One line of a rendered document (the schema of an item of `lines`).
pub struct TextLine;

impl utoipa::PartialSchema for TextLine {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        utoipa::openapi::ObjectBuilder::new()
            .schema_type(utoipa::openapi::schema::Type::String)
            .max_length(Some(64))
            .pattern(Some(r"^[0-9A-Za-z:.,# -]*$"))
            .description(Some("A line: digits, letters, space and `: - . , #`"))
            .into()
    }
}

impl utoipa::ToSchema for TextLine {}

impl RenderDocument {
    /// The image, or the field that is out of range.
    fn render(&self, max_pixels: u64) -> Result<image::RgbImage, ApiError> {
        use eyekey_core::imaging::glyphs;
        if self.lines.is_empty() || self.lines.len() > 16 {
            return Err(ApiError::invalid("lines", "give 1 to 16 lines"));
        }
        for (i, line) in self.lines.iter().enumerate() {
            if line.chars().count() > 64 {
                return Err(ApiError::invalid(
                    format!("lines[{i}]"),
                    "a line has at most 64 characters",
                ));
            }
            if let Some(c) = line.chars().find(|&c| !c.is_ascii() || !glyphs::has_glyph(c)) {
                return Err(ApiError::invalid(
                    format!("lines[{i}]"),
                    format!("{c:?} is not in the font (digits, letters, space and : - . , #)"),
                ));
            }
        }
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if !(8..=4096).contains(&v) {
                return Err(ApiError::invalid(
                    field,
                    format!("{field} must be within 8..=4096, got {v}"),
                ));
            }
        }
        if u64::from(self.width) * u64::from(self.height) > max_pixels {
            return Err(ApiError::TooLarge {
                field: Some("width".into()),
                message: format!(
                    "{}×{} exceeds the limit of {max_pixels} pixels",
                    self.width, self.height
                ),
            });
        }
        if !(1..=64).contains(&self.scale) {
            return Err(ApiError::invalid(
                "scale",
                format!("scale must be within 1..=64, got {}", self.scale),
            ));
        }
        let lines: Vec<&str> = self.lines.iter().map(String::as_str).collect();
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let glyph = (5 * i64::from(self.scale), 7 * i64::from(self.scale));
        let cells = glyphs::text_cells(&lines, self.width, self.height, self.scale);
        if cells
            .iter()
            .any(|c| c.x < 0 || c.y < 0 || c.x + glyph.0 > w || c.y + glyph.1 > h)
        {
            return Err(ApiError::invalid(
                "scale",
                format!(
                    "the text does not fit in {}×{} at scale {}: make the image larger or the scale smaller",
                    self.width, self.height, self.scale
                ),
            ));
        }
        Ok(glyphs::render_text(&lines, self.width, self.height, self.scale))
    }

    /// The layout a job on the rendered document is judged with, its secret characters masked (a job reads them
    /// from the document), or None when no character of the text is in the alphabet (nothing is secret); or the
    /// field that is wrong. Checked without drawing anything: `render` has placed every character.
    fn layout(&self) -> Result<Option<eyekey_core::evaluation::DocumentText>, ApiError> {
        use eyekey_core::evaluation::{DocumentText, KnownFontError};
        let text = DocumentText {
            lines: self.lines.clone(),
            scale: self.scale,
            alphabet: self.alphabet.clone().unwrap_or_else(|| "0123456789".into()),
        };
        match text.check_cheaply() {
            Ok(()) => Ok(Some(text.masked())),
            Err(KnownFontError::NothingSecret) => Ok(None),
            Err(e) => Err(ApiError::invalid("alphabet", e.to_string())),
        }
    }
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
    /// Whether it was rendered from text and keeps its layout (sealed): jobs on it are then judged by the
    /// known-font attacker; on any other document the target must reach the reads threshold of legibility.
    pub keeps_layout: bool,
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
            keeps_layout: r.sealed_layout.is_some(),
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

    let image = NewImage {
        bytes,
        content_type: header.content_type(),
        width: header.width,
        height: header.height,
        layout: None,
    };
    store_new(&state, &op, image, "document.upload").await
}

/// Render a document from text.
///
/// Draws the lines in eyekey's 5×7 font, black on white and centred, and stores the PNG as an upload would
/// be stored. The known-font attacker of a job on it can then be given the layout (`options.document_text`).
#[utoipa::path(
    post, path = "/v1/documents/text", tag = "documents",
    request_body = RenderDocument,
    responses(
        (status = 201, description = "Rendered and stored", body = DocumentView),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 413, description = "More pixels than the document limit", body = ErrorBody),
        (status = 422, description = "A character outside the font, or text that does not fit; `field` names it", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn render_document(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    ApiJson(body): ApiJson<RenderDocument>,
) -> Result<(StatusCode, Json<DocumentView>), ApiError> {
    let max_pixels = state.config.limits.max_document_pixels;
    let (png, width, height, layout) = tokio::task::spawn_blocking(move || {
        let image = body.render(max_pixels)?;
        let layout = body
            .layout()?
            .map(|l| serde_json::to_vec(&l))
            .transpose()
            .map_err(internal)?;
        let (width, height) = image.dimensions();
        let mut png = std::io::Cursor::new(Vec::new());
        image.write_to(&mut png, image::ImageFormat::Png).map_err(internal)?;
        Ok::<_, ApiError>((png.into_inner(), width, height, layout))
    })
    .await
    .map_err(internal)??;
    let image = NewImage {
        bytes: Bytes::from(png),
        content_type: "image/png",
        width,
        height,
        layout,
    };
    store_new(&state, &op, image, "document.render").await
}

/// A checked image to store, with the layout of one rendered from text (`DocumentText` JSON).
struct NewImage<'a> {
    bytes: Bytes,
    content_type: &'a str,
    width: u32,
    height: u32,
    layout: Option<Vec<u8>>,
}

/// Seals a checked image (and its layout) under a new document id and records it.
async fn store_new(
    state: &AppState,
    op: &Operator<scope::Submit>,
    image: NewImage<'_>,
    action: &str,
) -> Result<(StatusCode, Json<DocumentView>), ApiError> {
    let NewImage {
        bytes,
        content_type,
        width,
        height,
        layout,
    } = image;
    let id = id_text(&Uuid::new_v4());
    let len = bytes.len() as i64;
    let stored = sealed::store_document(&state.objects, &state.master_key, &id, bytes, layout)
        .await
        .map_err(ApiError::from_io)?;
    let row = store::documents::insert(
        &state.writer,
        &store::documents::NewDocument {
            id: &id,
            content_mac: &stored.content_mac,
            content_type,
            bytes: len,
            width: width.into(),
            height: height.into(),
            path: &stored.path,
            data_key: &stored.data_key,
            sealed_layout: stored.sealed_layout.as_deref(),
        },
    )
    .await?;
    store::audit::record(&state.writer, &op.actor(), action, &format!("documents/{id}")).await?;
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

/// Read a document's image, as uploaded (or rendered), opened from its sealed file. Every read is audited
/// (`document.read`).
#[utoipa::path(
    get, path = "/v1/documents/{id}/image", tag = "documents",
    params(("id" = Uuid, Path, description = "Document id")),
    responses(
        (status = 200, description = "The image", content(("image/png"), ("image/jpeg"))),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 404, description = "No such document", body = ErrorBody),
    ),
    security(("operator" = ["submit", "admin"]))
)]
pub async fn get_document_image(
    State(state): State<AppState>,
    op: Operator<scope::Submit>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<axum::response::Response, ApiError> {
    let row = store::documents::get(&state.db, &id_text(&id))
        .await?
        .ok_or(ApiError::NotFound("document"))?;
    let bytes = match sealed::open_document(&state.objects, &state.master_key, &row).await {
        Ok(bytes) => bytes,
        Err(sealed::OpenError::Missing) => return Err(ApiError::NotFound("document")),
        Err(sealed::OpenError::Io(e)) => return Err(ApiError::from_io(e)),
        Err(e) => return Err(internal(anyhow::anyhow!("document {}: {e}", row.id))),
    };
    store::audit::record(
        &state.writer,
        &op.actor(),
        "document.read",
        &format!("documents/{}", row.id),
    )
    .await?;
    let content_type = axum::http::HeaderValue::from_str(&row.content_type).map_err(internal)?;
    Ok((
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, axum::http::HeaderValue::from_static("no-store")),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                axum::http::HeaderValue::from_static("nosniff"),
            ),
        ],
        bytes,
    )
        .into_response())
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
