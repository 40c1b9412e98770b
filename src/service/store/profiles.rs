//! Vision profiles: metadata rows and sealed versions.

use sqlx::AnyPool;

use super::{now_ms, Cursor, Writer};
use crate::service::crypto::{profile_aad, MasterKey};

/// Metadata of a profile (never its contents).
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct ProfileRow {
    /// Id.
    pub id: String,
    /// Operator's label.
    pub label: Option<String>,
    /// Latest version.
    pub current_version: i64,
    /// Set when deleted.
    pub deleted_at: Option<i64>,
    /// First enrolment.
    pub created_at: i64,
    /// Latest enrolment.
    pub updated_at: i64,
}

/// A sealed version.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct ProfileVersionRow {
    /// Profile id.
    pub profile_id: String,
    /// Version (1, 2, ...).
    pub version: i64,
    /// AEAD nonce.
    pub nonce: Vec<u8>,
    /// AEAD ciphertext.
    pub ciphertext: Vec<u8>,
    /// When enrolled.
    pub created_at: i64,
}

impl ProfileVersionRow {
    /// Opens the sealed profile JSON.
    pub fn open(&self, key: &MasterKey) -> anyhow::Result<Vec<u8>> {
        Ok(key.open(
            &self.nonce,
            &self.ciphertext,
            &profile_aad(&self.profile_id, self.version),
        )?)
    }
}

const COLUMNS: &str = "id, label, current_version, deleted_at, created_at, updated_at";

/// Enrols a new profile as version 1.
pub async fn insert(
    writer: &Writer,
    key: &MasterKey,
    id: &str,
    label: Option<&str>,
    profile_json: &[u8],
) -> anyhow::Result<ProfileRow> {
    let pool = &writer.0;
    let now = now_ms();
    let sealed = key.seal(profile_json, &profile_aad(id, 1))?;
    let mut tx = pool.begin().await?;
    let row = sqlx::query_as::<_, ProfileRow>(&format!(
        "INSERT INTO profiles (id, label, current_version, created_at, updated_at) VALUES ($1, $2, 1, $3, $4)
         RETURNING {COLUMNS}"
    ))
    .bind(id)
    .bind(label)
    .bind(now)
    .bind(now)
    .fetch_one(&mut *tx)
    .await?;
    sqlx::query(
        "INSERT INTO profile_versions (profile_id, version, nonce, ciphertext, created_at) VALUES ($1, 1, $2, $3, $4)",
    )
    .bind(id)
    .bind(sealed.nonce)
    .bind(sealed.ciphertext)
    .bind(now)
    .execute(&mut *tx)
    .await?;
    tx.commit().await?;
    Ok(row)
}

/// Re-enrols: adds version `current_version + 1` and makes it current. `None` if no such live profile.
pub async fn add_version(
    writer: &Writer,
    key: &MasterKey,
    id: &str,
    label: Option<&str>,
    profile_json: &[u8],
) -> anyhow::Result<Option<ProfileRow>> {
    let pool = &writer.0;
    let now = now_ms();
    // The transaction's first statement writes, so it takes SQLite's write lock at once: concurrent
    // re-enrolments serialise and get distinct versions (no read-then-upgrade deadlock).
    let mut tx = pool.begin().await?;
    let row = sqlx::query_as::<_, ProfileRow>(&format!(
        "UPDATE profiles SET current_version = current_version + 1, updated_at = $1, label = COALESCE($2, label)
         WHERE id = $3 AND deleted_at IS NULL RETURNING {COLUMNS}"
    ))
    .bind(now)
    .bind(label)
    .bind(id)
    .fetch_optional(&mut *tx)
    .await?;
    let Some(row) = row else {
        return Ok(None);
    };
    let sealed = key.seal(profile_json, &profile_aad(id, row.current_version))?;
    sqlx::query(
        "INSERT INTO profile_versions (profile_id, version, nonce, ciphertext, created_at) VALUES ($1, $2, $3, $4, $5)",
    )
    .bind(id)
    .bind(row.current_version)
    .bind(sealed.nonce)
    .bind(sealed.ciphertext)
    .bind(now)
    .execute(&mut *tx)
    .await?;
    tx.commit().await?;
    Ok(Some(row))
}

/// A live (not deleted) profile's metadata.
pub async fn get(pool: &AnyPool, id: &str) -> Result<Option<ProfileRow>, sqlx::Error> {
    sqlx::query_as::<_, ProfileRow>(&format!(
        "SELECT {COLUMNS} FROM profiles WHERE id = $1 AND deleted_at IS NULL"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// One sealed version of a live profile.
pub async fn get_version(pool: &AnyPool, id: &str, version: i64) -> Result<Option<ProfileVersionRow>, sqlx::Error> {
    sqlx::query_as::<_, ProfileVersionRow>(
        "SELECT v.profile_id, v.version, v.nonce, v.ciphertext, v.created_at
         FROM profile_versions v JOIN profiles p ON p.id = v.profile_id
         WHERE v.profile_id = $1 AND v.version = $2 AND p.deleted_at IS NULL",
    )
    .bind(id)
    .bind(version)
    .fetch_optional(pool)
    .await
}

/// Live profiles, newest first.
pub async fn list(pool: &AnyPool, limit: u32, cursor: Option<&Cursor>) -> Result<Vec<ProfileRow>, sqlx::Error> {
    super::list_page(pool, "profiles", COLUMNS, true, limit, cursor).await
}

/// Deletes a profile: its sealed versions are removed, the metadata row stays as a tombstone, and every job
/// it was the target or an observer of is deleted ([`super::jobs::purge`]). Returns what to remove from the
/// disk, `None` if there was no such live profile.
pub async fn delete(writer: &Writer, id: &str) -> Result<Option<super::jobs::Purged>, sqlx::Error> {
    let pool = &writer.0;
    let now = now_ms();
    let mut tx = pool.begin().await?;
    let done = sqlx::query("UPDATE profiles SET deleted_at = $1, updated_at = $2 WHERE id = $3 AND deleted_at IS NULL")
        .bind(now)
        .bind(now)
        .bind(id)
        .execute(&mut *tx)
        .await?
        .rows_affected()
        == 1;
    if !done {
        return Ok(None);
    }
    sqlx::query("DELETE FROM profile_versions WHERE profile_id = $1")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    // Everything derived from the profile goes with it: every job it was the target or an observer of.
    let purged = super::jobs::purge(
        &mut tx,
        super::jobs::JobSet::OfProfile(id),
        "a profile of the job was deleted",
        now,
    )
    .await?;
    tx.commit().await?;
    Ok(Some(purged))
}
