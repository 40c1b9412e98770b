//! SQLite persistence: connection set-up, migrations and the queries of each resource.
//!
//! Queries are runtime-checked (`sqlx::query_as`) so no database is needed at build time.

pub mod audit;
pub mod displays;
pub mod documents;
pub mod ids;
pub mod jobs;
pub mod profiles;
pub mod tokens;

use std::path::Path;
use std::str::FromStr as _;
use std::time::Duration;

use chrono::{DateTime, TimeZone as _, Utc};
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;

/// The migrations in `migrations/`, embedded in the binary.
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!();

/// The single connection through which every write goes.
///
/// SQLite allows one writer at a time; when several connections write at once, the losers wait in SQLite's
/// busy handler, which sleeps in steps of milliseconds. Funnelling writes through one connection makes
/// them queue in the pool instead (fair, no sleeping), while reads use the reader pool and never wait for
/// writes (WAL). Write functions take a `&Writer`, so a write cannot go through a reader by mistake.
#[derive(Clone, Debug)]
pub struct Writer(pub SqlitePool);

/// Opens (creating if needed) the database at `path` as a reader pool and the writer: WAL journal, a busy
/// timeout (for checkpoints and other processes), foreign keys on, and `secure_delete` so deleted
/// ciphertexts are overwritten.
pub async fn connect(path: &Path) -> Result<(SqlitePool, Writer), sqlx::Error> {
    let options = SqliteConnectOptions::from_str("sqlite:")?
        .filename(path)
        .create_if_missing(true)
        .journal_mode(SqliteJournalMode::Wal)
        .synchronous(SqliteSynchronous::Normal)
        .busy_timeout(Duration::from_secs(10))
        .foreign_keys(true)
        .pragma("secure_delete", "on");
    let pool = |n: u32| {
        SqlitePoolOptions::new()
            .max_connections(n)
            .acquire_timeout(Duration::from_secs(30))
            .connect_with(options.clone())
    };
    // The writer first: it creates the file and switches it to WAL before the readers open it.
    let writer = Writer(pool(1).await?);
    let readers = pool(8).await?;
    Ok((readers, writer))
}

/// Applies the embedded migrations.
pub async fn migrate(writer: &Writer) -> Result<(), sqlx::migrate::MigrateError> {
    MIGRATOR.run(&writer.0).await
}

/// True when every embedded migration has been applied successfully.
pub async fn migrations_applied(pool: &SqlitePool) -> Result<bool, sqlx::Error> {
    let applied: Vec<(i64,)> = sqlx::query_as("SELECT version FROM _sqlx_migrations WHERE success = 1")
        .fetch_all(pool)
        .await?;
    Ok(MIGRATOR.iter().all(|m| applied.iter().any(|(v,)| *v == m.version)))
}

/// Moves every page of the write-ahead log into the database and truncates the log to zero bytes, so the
/// old page images it holds (a deleted key, a deleted profile's ciphertext) are gone from it too. With
/// `secure_delete` on, the freed space in the database file itself is zeroed. Returns whether the
/// checkpoint completed (a long-running reader can keep it from finishing; the next one catches up).
pub async fn checkpoint(writer: &Writer) -> Result<bool, sqlx::Error> {
    let (busy, _, _): (i64, i64, i64) = sqlx::query_as("PRAGMA wal_checkpoint(TRUNCATE)")
        .fetch_one(&writer.0)
        .await?;
    Ok(busy == 0)
}

/// Now, in the database's time unit (Unix milliseconds).
pub fn now_ms() -> i64 {
    Utc::now().timestamp_millis()
}

/// Unix milliseconds to a UTC time.
pub fn to_time(ms: i64) -> DateTime<Utc> {
    Utc.timestamp_millis_opt(ms).single().unwrap_or_default()
}

/// A position in a listing ordered by (created_at, id) descending: the last item of the previous page.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cursor {
    /// `created_at` of the last item returned.
    pub created_at: i64,
    /// `id` of the last item returned.
    pub id: String,
}

impl Cursor {
    /// Text form handed to clients: `<created_at>.<id>`, the keyset position of the last item of a page. Any
    /// text of that form is a position, so the schema's pattern ([`CURSOR_PATTERN`]) says all there is to say.
    pub fn encode(&self) -> String {
        format!("{}.{}", self.created_at, self.id)
    }

    /// Parses the text form; `None` when it does not match [`CURSOR_PATTERN`].
    pub fn decode(text: &str) -> Option<Self> {
        let (at, id) = text.split_once('.')?;
        let digits = |s: &str, max: usize| (1..=max).contains(&s.len()) && s.bytes().all(|b| b.is_ascii_digit());
        let id_ok = (1..=36).contains(&id.len())
            && id
                .bytes()
                .all(|b| b.is_ascii_digit() || b.is_ascii_lowercase() || b == b'-');
        if !digits(at, 18) || !id_ok {
            return None;
        }
        Some(Self {
            created_at: at.parse().ok()?,
            id: id.to_string(),
        })
    }
}

/// The form of a listing's cursor (see [`Cursor::encode`]).
pub const CURSOR_PATTERN: &str = r"^[0-9]{1,18}\.[0-9a-z-]{1,36}$";

/// One page of `table`, newest first, by keyset pagination on (created_at, id): stable under concurrent
/// inserts, unlike OFFSET. `live_only` skips soft-deleted rows (tables with a `deleted_at` column).
pub async fn list_page<T>(
    pool: &sqlx::SqlitePool,
    table: &str,
    columns: &str,
    live_only: bool,
    limit: u32,
    cursor: Option<&Cursor>,
) -> Result<Vec<T>, sqlx::Error>
where
    T: for<'r> sqlx::FromRow<'r, sqlx::sqlite::SqliteRow> + Send + Unpin,
{
    let (at, id) = cursor.map(|c| (c.created_at, c.id.as_str())).unwrap_or((i64::MAX, ""));
    let live = if live_only { "deleted_at IS NULL AND " } else { "" };
    // `table` and `columns` are compile-time constants of the store modules, never client input.
    sqlx::query_as::<_, T>(&format!(
        "SELECT {columns} FROM {table}
         WHERE {live}(created_at < ? OR (created_at = ? AND id < ?) OR ? = '')
         ORDER BY created_at DESC, id DESC LIMIT ?"
    ))
    .bind(at)
    .bind(at)
    .bind(id)
    .bind(id)
    .bind(limit as i64)
    .fetch_all(pool)
    .await
}

/// Page size bounds for listings.
pub const DEFAULT_PAGE: u32 = 50;
/// Largest page a client may ask for.
pub const MAX_PAGE: u32 = 200;

/// The store of a sealed value that proves the master key has not changed since the data was written.
pub async fn check_master_key(writer: &Writer, key: &super::crypto::MasterKey) -> anyhow::Result<()> {
    const NAME: &str = "master_key_check";
    const PLAIN: &[u8] = b"eyekey master key check";
    let pool = &writer.0;
    let row: Option<(Vec<u8>,)> = sqlx::query_as("SELECT value FROM settings WHERE name = ?")
        .bind(NAME)
        .fetch_optional(pool)
        .await?;
    match row {
        Some((value,)) => {
            let (nonce, ct) = value.split_at(super::crypto::NONCE_LEN.min(value.len()));
            match key.open(nonce, ct, NAME.as_bytes()) {
                Ok(p) if p == PLAIN => Ok(()),
                _ => anyhow::bail!(
                    "the master key does not match the one this data directory's profiles were sealed with"
                ),
            }
        }
        None => {
            let sealed = key.seal(PLAIN, NAME.as_bytes())?;
            let mut value = sealed.nonce;
            value.extend_from_slice(&sealed.ciphertext);
            sqlx::query("INSERT INTO settings (name, value, created_at) VALUES (?, ?, ?)")
                .bind(NAME)
                .bind(value)
                .bind(now_ms())
                .execute(pool)
                .await?;
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cursor_round_trips_and_rejects_garbage() {
        let c = Cursor {
            created_at: 1_700_000_000_123,
            id: "3f1c".into(),
        };
        assert_eq!(c.encode(), "1700000000123.3f1c");
        assert_eq!(Cursor::decode(&c.encode()), Some(c));
        for garbage in [
            "not a cursor",
            "",
            "1.",
            ".a",
            "1.A",
            "1.a.b",
            "1234567890123456789.a",
            "MTcwMHwzZjFj",
        ] {
            assert_eq!(Cursor::decode(garbage), None, "{garbage:?}");
        }
    }
}
