//! The append-only audit log.

use sqlx::AnyPool;

use super::{now_ms, Cursor, Writer};

/// One audit entry.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct AuditRow {
    /// Sequence number.
    pub id: i64,
    /// `operator` or `display:<id>`.
    pub actor: String,
    /// What was done, e.g. `profile.create`.
    pub action: String,
    /// To what, e.g. `profiles/<id>`.
    pub resource: String,
    /// When (Unix ms).
    pub created_at: i64,
}

/// Appends an entry.
pub async fn record(writer: &Writer, actor: &str, action: &str, resource: &str) -> Result<(), sqlx::Error> {
    let pool = &writer.0;
    sqlx::query("INSERT INTO audit_log (actor, action, resource, created_at) VALUES ($1, $2, $3, $4)")
        .bind(actor)
        .bind(action)
        .bind(resource)
        .bind(now_ms())
        .execute(pool)
        .await?;
    Ok(())
}

/// Entries newest first, after `cursor` (whose `id` is the sequence number); with `resource`, only those about
/// it or about what lies under it (`resource/…`).
pub async fn list(
    pool: &AnyPool,
    limit: u32,
    cursor: Option<&Cursor>,
    resource: Option<&str>,
) -> Result<Vec<AuditRow>, sqlx::Error> {
    let before = cursor.and_then(|c| c.id.parse::<i64>().ok()).unwrap_or(i64::MAX);
    match resource {
        None => sqlx::query_as::<_, AuditRow>(
            "SELECT id, actor, action, resource, created_at FROM audit_log WHERE id < $1 ORDER BY id DESC LIMIT $2",
        )
        .bind(before)
        .bind(limit as i64),
        // `r/…` are the texts from `r/` up to, not including, `r0` ('0' follows '/' in ASCII): a prefix match
        // that needs no LIKE escaping.
        Some(r) => sqlx::query_as::<_, AuditRow>(
            "SELECT id, actor, action, resource, created_at FROM audit_log \
             WHERE id < $1 AND (resource = $2 OR (resource >= $3 AND resource < $4)) ORDER BY id DESC LIMIT $5",
        )
        .bind(before)
        .bind(r)
        .bind(format!("{r}/"))
        .bind(format!("{r}0"))
        .bind(limit as i64),
    }
    .fetch_all(pool)
    .await
}
