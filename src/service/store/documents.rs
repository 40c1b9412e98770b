//! Uploaded documents (metadata; the bytes are files under the data directory).

use sqlx::SqlitePool;

use super::{now_ms, Cursor, Writer};

/// A document row.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct DocumentRow {
    /// Id.
    pub id: String,
    /// SHA-256 of the uploaded bytes, hex.
    pub sha256: String,
    /// `image/png` or `image/jpeg`.
    pub content_type: String,
    /// Size of the upload.
    pub bytes: i64,
    /// Width in pixels.
    pub width: i64,
    /// Height in pixels.
    pub height: i64,
    /// Path of the stored file relative to the data directory.
    pub path: String,
    /// Upload time.
    pub created_at: i64,
}

const COLUMNS: &str = "id, sha256, content_type, bytes, width, height, path, created_at";

/// A new document's metadata.
#[derive(Clone, Debug)]
pub struct NewDocument<'a> {
    /// Id.
    pub id: &'a str,
    /// SHA-256, hex.
    pub sha256: &'a str,
    /// Content type.
    pub content_type: &'a str,
    /// Size.
    pub bytes: i64,
    /// Width.
    pub width: i64,
    /// Height.
    pub height: i64,
    /// Relative path.
    pub path: &'a str,
}

/// Records an uploaded document whose file is already in place.
pub async fn insert(writer: &Writer, d: &NewDocument<'_>) -> Result<DocumentRow, sqlx::Error> {
    let pool = &writer.0;
    sqlx::query_as::<_, DocumentRow>(&format!(
        "INSERT INTO documents (id, sha256, content_type, bytes, width, height, path, created_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, ?) RETURNING {COLUMNS}"
    ))
    .bind(d.id)
    .bind(d.sha256)
    .bind(d.content_type)
    .bind(d.bytes)
    .bind(d.width)
    .bind(d.height)
    .bind(d.path)
    .bind(now_ms())
    .fetch_one(pool)
    .await
}

/// One document.
pub async fn get(pool: &SqlitePool, id: &str) -> Result<Option<DocumentRow>, sqlx::Error> {
    sqlx::query_as::<_, DocumentRow>(&format!("SELECT {COLUMNS} FROM documents WHERE id = ?"))
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// Documents, newest first.
pub async fn list(pool: &SqlitePool, limit: u32, cursor: Option<&Cursor>) -> Result<Vec<DocumentRow>, sqlx::Error> {
    super::list_page(pool, "documents", COLUMNS, false, limit, cursor).await
}
