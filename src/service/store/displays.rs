//! Registered displays.

use sqlx::AnyPool;

use super::{now_ms, Cursor, Writer};

/// A display row.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct DisplayRow {
    /// Id.
    pub id: String,
    /// Operator's name for it.
    pub name: String,
    /// `DisplayGeometry` JSON.
    pub geometry: String,
    /// SHA-256 of its access token.
    pub token_hash: Vec<u8>,
    /// When the current token was issued.
    pub token_rotated_at: i64,
    /// Set when deleted.
    pub deleted_at: Option<i64>,
    /// Registration time.
    pub created_at: i64,
}

const COLUMNS: &str = "id, name, geometry, token_hash, token_rotated_at, deleted_at, created_at";

/// Registers a display.
pub async fn insert(
    writer: &Writer,
    id: &str,
    name: &str,
    geometry_json: &str,
    token_hash: &[u8],
) -> Result<DisplayRow, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    sqlx::query_as::<_, DisplayRow>(&format!(
        "INSERT INTO displays (id, name, geometry, token_hash, token_rotated_at, created_at)
         VALUES ($1, $2, $3, $4, $5, $6) RETURNING {COLUMNS}"
    ))
    .bind(id)
    .bind(name)
    .bind(geometry_json)
    .bind(token_hash)
    .bind(now)
    .bind(now)
    .fetch_one(pool)
    .await
}

/// A live display.
pub async fn get(pool: &AnyPool, id: &str) -> Result<Option<DisplayRow>, sqlx::Error> {
    sqlx::query_as::<_, DisplayRow>(&format!(
        "SELECT {COLUMNS} FROM displays WHERE id = $1 AND deleted_at IS NULL"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// The `DisplayGeometry` JSON of a display, live or deleted (jobs keep referring to deleted ones).
pub async fn geometry(pool: &AnyPool, id: &str) -> Result<Option<String>, sqlx::Error> {
    sqlx::query_scalar::<_, String>("SELECT geometry FROM displays WHERE id = $1")
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// The live display whose token has this hash (the hash column is unique and indexed).
pub async fn by_token_hash(pool: &AnyPool, hash: &[u8]) -> Result<Option<DisplayRow>, sqlx::Error> {
    sqlx::query_as::<_, DisplayRow>(&format!(
        "SELECT {COLUMNS} FROM displays WHERE token_hash = $1 AND deleted_at IS NULL"
    ))
    .bind(hash)
    .fetch_optional(pool)
    .await
}

/// Live displays, newest first.
pub async fn list(pool: &AnyPool, limit: u32, cursor: Option<&Cursor>) -> Result<Vec<DisplayRow>, sqlx::Error> {
    super::list_page(pool, "displays", COLUMNS, true, limit, cursor).await
}

/// Replaces the token hash; the old token stops working at once.
pub async fn rotate_token(writer: &Writer, id: &str, token_hash: &[u8]) -> Result<Option<DisplayRow>, sqlx::Error> {
    let pool = &writer.0;
    sqlx::query_as::<_, DisplayRow>(&format!(
        "UPDATE displays SET token_hash = $1, token_rotated_at = $2 WHERE id = $3 AND deleted_at IS NULL
         RETURNING {COLUMNS}"
    ))
    .bind(token_hash)
    .bind(now_ms())
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// Soft-deletes a display (its token stops working; its jobs keep their history) and cancels its
/// queued jobs, asking running ones to stop. Returns false if there was no such live display.
pub async fn delete(writer: &Writer, id: &str) -> Result<bool, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    let mut tx = pool.begin().await?;
    let done = sqlx::query("UPDATE displays SET deleted_at = $1 WHERE id = $2 AND deleted_at IS NULL")
        .bind(now)
        .bind(id)
        .execute(&mut *tx)
        .await?
        .rows_affected()
        == 1;
    if done {
        super::jobs::stop_jobs_of_display(&mut tx, id, "the display was deleted", now).await?;
    }
    tx.commit().await?;
    Ok(done)
}
