//! Scoped operator tokens: names, scopes and the SHA-256 of each secret.

use sqlx::AnyPool;

use super::{now_ms, Cursor, Writer};

/// A token row (never the secret).
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct TokenRow {
    /// Id.
    pub id: String,
    /// Name, recorded in the audit log.
    pub name: String,
    /// JSON array of scope names.
    pub scopes: String,
    /// SHA-256 of the secret.
    pub token_hash: Vec<u8>,
    /// When it was revoked, if it was.
    pub revoked_at: Option<i64>,
    /// Creation time.
    pub created_at: i64,
}

const COLUMNS: &str = "id, name, scopes, token_hash, revoked_at, created_at";

/// Stores a new token; `None` when a live token already has this name.
pub async fn insert(
    writer: &Writer,
    id: &str,
    name: &str,
    scopes: &str,
    hash: &[u8; 32],
) -> Result<Option<TokenRow>, sqlx::Error> {
    let r = sqlx::query_as::<_, TokenRow>(&format!(
        "INSERT INTO tokens (id, name, scopes, token_hash, created_at) VALUES ($1, $2, $3, $4, $5) RETURNING {COLUMNS}"
    ))
    .bind(id)
    .bind(name)
    .bind(scopes)
    .bind(&hash[..])
    .bind(now_ms())
    .fetch_one(&writer.0)
    .await;
    match r {
        Ok(row) => Ok(Some(row)),
        Err(sqlx::Error::Database(d)) if d.is_unique_violation() => Ok(None),
        Err(e) => Err(e),
    }
}

/// The live token with this hash.
pub async fn by_hash(pool: &AnyPool, hash: &[u8; 32]) -> Result<Option<TokenRow>, sqlx::Error> {
    sqlx::query_as::<_, TokenRow>(&format!(
        "SELECT {COLUMNS} FROM tokens WHERE token_hash = $1 AND revoked_at IS NULL"
    ))
    .bind(&hash[..])
    .fetch_optional(pool)
    .await
}

/// Live tokens, newest first.
pub async fn list(pool: &AnyPool, limit: u32, cursor: Option<&Cursor>) -> Result<Vec<TokenRow>, sqlx::Error> {
    let (at, id) = cursor.map(|c| (c.created_at, c.id.as_str())).unwrap_or((i64::MAX, ""));
    sqlx::query_as::<_, TokenRow>(&format!(
        "SELECT {COLUMNS} FROM tokens WHERE revoked_at IS NULL
           AND (created_at < $1 OR (created_at = $1 AND id < $2) OR $2 = '')
         ORDER BY created_at DESC, id DESC LIMIT $3"
    ))
    .bind(at)
    .bind(id)
    .bind(limit as i64)
    .fetch_all(pool)
    .await
}

/// Revokes a live token; false when there is none with this id.
pub async fn revoke(writer: &Writer, id: &str) -> Result<bool, sqlx::Error> {
    let r = sqlx::query("UPDATE tokens SET revoked_at = $1 WHERE id = $2 AND revoked_at IS NULL")
        .bind(now_ms())
        .bind(id)
        .execute(&writer.0)
        .await?;
    Ok(r.rows_affected() == 1)
}
