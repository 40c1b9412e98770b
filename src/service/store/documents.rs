//! Uploaded documents: metadata and wrapped data keys (the sealed bytes are files under the data directory).

use sqlx::AnyPool;

use super::{now_ms, Cursor, Writer};

/// A document row.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct DocumentRow {
    /// Id.
    pub id: String,
    /// Keyed HMAC-SHA256 of the uploaded bytes, hex (see [`crate::service::crypto::MasterKey::digest`]).
    pub content_mac: String,
    /// `image/png` or `image/jpeg`.
    pub content_type: String,
    /// Size of the upload.
    pub bytes: i64,
    /// Width in pixels.
    pub width: i64,
    /// Height in pixels.
    pub height: i64,
    /// Path of the stored (sealed) file relative to the data directory.
    pub path: String,
    /// The data key the file is sealed under, wrapped by the master key; `None` for a document stored
    /// before sealing (sealed at start) or deleted.
    pub data_key: Option<Vec<u8>>,
    /// For a document rendered from text: its layout (`DocumentText` JSON) sealed under its data key.
    pub sealed_layout: Option<Vec<u8>>,
    /// Upload time.
    pub created_at: i64,
}

const COLUMNS: &str = "id, content_mac, content_type, bytes, width, height, path, data_key, sealed_layout, created_at";

/// A new document's metadata.
#[derive(Clone, Debug)]
pub struct NewDocument<'a> {
    /// Id.
    pub id: &'a str,
    /// Keyed MAC, hex.
    pub content_mac: &'a str,
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
    /// Wrapped data key.
    pub data_key: &'a [u8],
    /// The layout of a document rendered from text, sealed under the data key.
    pub sealed_layout: Option<&'a [u8]>,
}

/// Records an uploaded document whose sealed file is already in place.
pub async fn insert(writer: &Writer, d: &NewDocument<'_>) -> Result<DocumentRow, sqlx::Error> {
    let pool = &writer.0;
    sqlx::query_as::<_, DocumentRow>(&format!(
        "INSERT INTO documents (id, content_mac, content_type, bytes, width, height, path, data_key, sealed_layout, created_at)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) RETURNING {COLUMNS}"
    ))
    .bind(d.id)
    .bind(d.content_mac)
    .bind(d.content_type)
    .bind(d.bytes)
    .bind(d.width)
    .bind(d.height)
    .bind(d.path)
    .bind(d.data_key)
    .bind(d.sealed_layout)
    .bind(now_ms())
    .fetch_one(pool)
    .await
}

/// One live (not deleted) document.
pub async fn get(pool: &AnyPool, id: &str) -> Result<Option<DocumentRow>, sqlx::Error> {
    sqlx::query_as::<_, DocumentRow>(&format!(
        "SELECT {COLUMNS} FROM documents WHERE id = $1 AND deleted_at IS NULL"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// Live documents, newest first.
pub async fn list(pool: &AnyPool, limit: u32, cursor: Option<&Cursor>) -> Result<Vec<DocumentRow>, sqlx::Error> {
    super::list_page(pool, "documents", COLUMNS, true, limit, cursor).await
}

/// Live documents stored before sealing (no data key yet).
pub async fn unsealed(pool: &AnyPool) -> Result<Vec<DocumentRow>, sqlx::Error> {
    sqlx::query_as::<_, DocumentRow>(&format!(
        "SELECT {COLUMNS} FROM documents WHERE data_key IS NULL AND deleted_at IS NULL"
    ))
    .fetch_all(pool)
    .await
}

/// Records that a document stored before sealing is now sealed at `path` under `data_key`.
pub async fn set_sealed(
    writer: &Writer,
    id: &str,
    path: &str,
    content_mac: &str,
    data_key: &[u8],
) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE documents SET path = $1, content_mac = $2, data_key = $3 WHERE id = $4 AND deleted_at IS NULL")
        .bind(path)
        .bind(content_mac)
        .bind(data_key)
        .bind(id)
        .execute(&writer.0)
        .await?;
    Ok(())
}

/// What a deletion left to remove from the disk: files and directories relative to the data directory.
/// Their data keys are already gone, so what remains cannot be opened even if removing it fails.
#[derive(Clone, Debug, Default)]
pub struct Leftovers {
    /// Sealed files and job output directories.
    pub paths: Vec<String>,
    /// Jobs that were deleted.
    pub jobs: Vec<String>,
    /// Documents that were deleted.
    pub documents: Vec<String>,
}

/// Deletes documents (one by id, or every one created before a time): the row stays as a tombstone
/// without its data key, and every job that showed it is deleted too ([`super::jobs::purge`]). Returns
/// what to remove from the disk, `None` when `id` named no live document.
pub async fn delete(writer: &Writer, which: Which<'_>, now: i64) -> Result<Option<Leftovers>, sqlx::Error> {
    let mut tx = writer.0.begin().await?;
    let (id, before) = match which {
        Which::One(id) => (Some(id), None),
        Which::CreatedBefore(t) => (None, Some(t)),
    };
    // A NULL on either side makes its comparison false, so exactly one of the two selects.
    let doomed: Vec<(String, String)> =
        sqlx::query_as("SELECT id, path FROM documents WHERE deleted_at IS NULL AND (id = $1 OR created_at < $2)")
            .bind(id)
            .bind(before)
            .fetch_all(&mut *tx)
            .await?;
    if doomed.is_empty() && matches!(which, Which::One(_)) {
        return Ok(None);
    }
    let mut left = Leftovers::default();
    for (id, path) in doomed {
        sqlx::query("UPDATE documents SET deleted_at = $1, data_key = NULL, sealed_layout = NULL WHERE id = $2")
            .bind(now)
            .bind(&id)
            .execute(&mut *tx)
            .await?;
        let jobs = super::jobs::purge(
            &mut tx,
            super::jobs::JobSet::OfDocument(&id),
            "the document was deleted",
            now,
        )
        .await?;
        left.paths.push(path);
        left.documents.push(id.clone());
        left.paths.extend(jobs.paths);
        left.jobs.extend(jobs.jobs);
    }
    tx.commit().await?;
    Ok(Some(left))
}

/// Which documents a deletion takes.
#[derive(Clone, Copy, Debug)]
pub enum Which<'a> {
    /// This one.
    One(&'a str),
    /// Every one created before this time (Unix ms): expiry.
    CreatedBefore(i64),
}
