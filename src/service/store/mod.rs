//! Persistence on SQLite (the embedded default) or PostgreSQL (for several processes and machines):
//! connection set-up, migrations and the queries of each resource.
//!
//! Both backends are reached through sqlx's `Any` driver with one text per query: placeholders are `$N`
//! (which both accept), values are TEXT, BIGINT, DOUBLE and BLOB/BYTEA, and the few statements that differ
//! (the queue's row locking, JSON, the WAL checkpoint) ask [`Backend`] for their dialect. Queries are
//! runtime-checked (`sqlx::query_as`) so no database is needed at build time.

pub mod audit;
pub mod displays;
pub mod documents;
pub mod ids;
pub mod jobs;
pub mod objects;
pub mod profiles;
pub mod tokens;

use std::path::{Path, PathBuf};
use std::time::Duration;

use chrono::{DateTime, TimeZone as _, Utc};
use sqlx::any::AnyPoolOptions;
use sqlx::{AnyConnection, AnyPool, Executor as _};

/// The SQLite migrations in `migrations/sqlite/`, embedded in the binary.
pub static SQLITE_MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("./migrations/sqlite");
/// The PostgreSQL migrations in `migrations/postgres/`, embedded in the binary.
pub static POSTGRES_MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("./migrations/postgres");

/// Which database engine holds the data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// One file in the data directory: one machine, one process.
    Sqlite,
    /// A PostgreSQL server: any number of API and worker processes, on any machines.
    Postgres,
}

impl Backend {
    /// The backend a pool connects to.
    pub fn of(pool: &AnyPool) -> Self {
        Self::of_scheme(pool.connect_options().database_url.scheme())
    }

    /// The backend of a connection (inside a transaction).
    pub fn of_connection(conn: &AnyConnection) -> Self {
        if conn.backend_name().eq_ignore_ascii_case("postgresql") {
            Self::Postgres
        } else {
            Self::Sqlite
        }
    }

    fn of_scheme(scheme: &str) -> Self {
        match scheme {
            "postgres" | "postgresql" => Self::Postgres,
            _ => Self::Sqlite,
        }
    }

    /// Its embedded migrations.
    pub fn migrator(self) -> &'static sqlx::migrate::Migrator {
        match self {
            Self::Sqlite => &SQLITE_MIGRATOR,
            Self::Postgres => &POSTGRES_MIGRATOR,
        }
    }

    /// The name operators know it by.
    pub fn name(self) -> &'static str {
        match self {
            Self::Sqlite => "SQLite",
            Self::Postgres => "PostgreSQL",
        }
    }
}

/// Where the database is: `--database-url`, or the SQLite file in the data directory.
#[derive(Clone, PartialEq, Eq)]
pub enum Location {
    /// A SQLite file (created if missing).
    Sqlite(PathBuf),
    /// A PostgreSQL connection URL (`postgres://user:password@host:port/db?sslmode=…`).
    Postgres(String),
}

impl Location {
    /// Parses `sqlite://PATH`, `sqlite:PATH`, `postgres://…` or `postgresql://…`.
    pub fn parse(url: &str) -> Result<Self, String> {
        if let Some(path) = url.strip_prefix("sqlite://").or_else(|| url.strip_prefix("sqlite:")) {
            let path = path.split('?').next().unwrap_or_default();
            if path.is_empty() || path == ":memory:" {
                return Err("a SQLite database URL must name a file: sqlite:///var/lib/eyekey/eyekey.db".into());
            }
            return Ok(Self::Sqlite(PathBuf::from(path)));
        }
        if url.starts_with("postgres://") || url.starts_with("postgresql://") {
            return Ok(Self::Postgres(url.to_string()));
        }
        Err("a database URL starts with sqlite:// or postgres://".into())
    }

    /// The backend it names.
    pub fn backend(&self) -> Backend {
        match self {
            Self::Sqlite(_) => Backend::Sqlite,
            Self::Postgres(_) => Backend::Postgres,
        }
    }
}

/// What to log of a location: never a password.
impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Sqlite(path) => write!(f, "sqlite://{}", path.display()),
            Self::Postgres(url) => match url.parse::<url::Url>() {
                Ok(mut u) => {
                    if u.password().is_some() {
                        let _ = u.set_password(Some("***"));
                    }
                    write!(f, "{u}")
                }
                Err(_) => f.write_str("postgres://(unparsable URL)"),
            },
        }
    }
}

impl std::fmt::Debug for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(self, f)
    }
}

/// The connection through which every write goes.
///
/// On SQLite this is a single connection: SQLite allows one writer at a time; when several connections
/// write at once, the losers wait in SQLite's busy handler, which sleeps in steps of milliseconds.
/// Funnelling writes through one connection makes them queue in the pool instead (fair, no sleeping), while
/// reads use the reader pool and never wait for writes (WAL). On PostgreSQL, which has row locks, it is the
/// same pool as the readers. Write functions take a `&Writer`, so a write cannot go through a reader by
/// mistake.
#[derive(Clone, Debug)]
pub struct Writer(pub AnyPool);

impl Writer {
    /// The backend written to.
    pub fn backend(&self) -> Backend {
        Backend::of(&self.0)
    }
}

/// The SQLite connection settings: WAL journal, a busy timeout (for checkpoints and other processes),
/// foreign keys on, and `secure_delete` so deleted ciphertexts are overwritten.
const SQLITE_PRAGMAS: &str = "PRAGMA journal_mode = WAL; PRAGMA synchronous = NORMAL; PRAGMA busy_timeout = 10000; \
     PRAGMA foreign_keys = ON; PRAGMA secure_delete = ON;";

/// Opens the database as a reader pool and the writer. A SQLite file is created if missing.
pub async fn connect(location: &Location) -> Result<(AnyPool, Writer), sqlx::Error> {
    sqlx::any::install_default_drivers();
    match location {
        Location::Sqlite(path) => {
            let url = sqlite_url(path);
            let pool = |n: u32| {
                AnyPoolOptions::new()
                    .max_connections(n)
                    .acquire_timeout(Duration::from_secs(30))
                    .after_connect(|conn, _| {
                        Box::pin(async move {
                            conn.execute(SQLITE_PRAGMAS).await?;
                            Ok(())
                        })
                    })
                    .connect(&url)
            };
            // The writer first: it creates the file and switches it to WAL before the readers open it.
            let writer = Writer(pool(1).await?);
            let readers = pool(8).await?;
            Ok((readers, writer))
        }
        Location::Postgres(url) => {
            let pool = AnyPoolOptions::new()
                .max_connections(16)
                .acquire_timeout(Duration::from_secs(30))
                .connect(url)
                .await?;
            Ok((pool.clone(), Writer(pool)))
        }
    }
}

/// `sqlite://` URL of a file, created if missing (`mode=rwc`); the path is percent-encoded.
fn sqlite_url(path: &Path) -> String {
    let text = path.to_string_lossy();
    let mut encoded = String::with_capacity(text.len());
    for b in text.bytes() {
        if b.is_ascii_alphanumeric() || b"/-_.~".contains(&b) {
            encoded.push(b as char);
        } else {
            encoded.push_str(&format!("%{b:02X}"));
        }
    }
    format!("sqlite://{encoded}?mode=rwc")
}

/// Applies the embedded migrations of the writer's backend. Several processes may start at once: sqlx
/// holds an advisory lock (PostgreSQL) or the write lock (SQLite) while it migrates, and a migration
/// applied by another process is skipped.
pub async fn migrate(writer: &Writer) -> Result<(), sqlx::migrate::MigrateError> {
    writer.backend().migrator().run(&writer.0).await
}

/// True when every embedded migration has been applied successfully.
pub async fn migrations_applied(pool: &AnyPool) -> Result<bool, sqlx::Error> {
    let applied: Vec<(i64,)> = sqlx::query_as("SELECT version FROM _sqlx_migrations WHERE success = TRUE")
        .fetch_all(pool)
        .await?;
    Ok(Backend::of(pool)
        .migrator()
        .iter()
        .all(|m| applied.iter().any(|(v,)| *v == m.version)))
}

/// Moves every page of SQLite's write-ahead log into the database and truncates the log to zero bytes, so
/// the old page images it holds (a deleted key, a deleted profile's ciphertext) are gone from it too. With
/// `secure_delete` on, the freed space in the database file itself is zeroed. Returns whether the
/// checkpoint completed (a long-running reader can keep it from finishing; the next one catches up).
/// PostgreSQL keeps no such log within reach of the service: nothing to do (see docs/design.md §7).
pub async fn checkpoint(writer: &Writer) -> Result<bool, sqlx::Error> {
    if writer.backend() == Backend::Postgres {
        return Ok(true);
    }
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
    pool: &AnyPool,
    table: &str,
    columns: &str,
    live_only: bool,
    limit: u32,
    cursor: Option<&Cursor>,
) -> Result<Vec<T>, sqlx::Error>
where
    T: for<'r> sqlx::FromRow<'r, sqlx::any::AnyRow> + Send + Unpin,
{
    let (at, id) = cursor.map(|c| (c.created_at, c.id.as_str())).unwrap_or((i64::MAX, ""));
    let live = if live_only { "deleted_at IS NULL AND " } else { "" };
    // `table` and `columns` are compile-time constants of the store modules, never client input.
    sqlx::query_as::<_, T>(&format!(
        "SELECT {columns} FROM {table}
         WHERE {live}(created_at < $1 OR (created_at = $2 AND id < $3) OR $4 = '')
         ORDER BY created_at DESC, id DESC LIMIT $5"
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

/// True when the database already holds the value sealed under a master key (data was stored under one).
pub async fn holds_master_key_check(writer: &Writer) -> Result<bool, sqlx::Error> {
    let row: Option<(String,)> = sqlx::query_as("SELECT name FROM settings WHERE name = 'master_key_check'")
        .fetch_optional(&writer.0)
        .await?;
    Ok(row.is_some())
}

/// The store of a sealed value that proves the master key has not changed since the data was written.
pub async fn check_master_key(writer: &Writer, key: &super::crypto::MasterKey) -> anyhow::Result<()> {
    const NAME: &str = "master_key_check";
    const PLAIN: &[u8] = b"eyekey master key check";
    let pool = &writer.0;
    // The first process to start writes the sentinel; processes starting at the same moment (several API
    // processes on one PostgreSQL database) insert nothing and check the one that won.
    let sealed = key.seal(PLAIN, NAME.as_bytes())?;
    let mut value = sealed.nonce;
    value.extend_from_slice(&sealed.ciphertext);
    sqlx::query("INSERT INTO settings (name, value, created_at) VALUES ($1, $2, $3) ON CONFLICT (name) DO NOTHING")
        .bind(NAME)
        .bind(value)
        .bind(now_ms())
        .execute(pool)
        .await?;
    let (value,): (Vec<u8>,) = sqlx::query_as("SELECT value FROM settings WHERE name = $1")
        .bind(NAME)
        .fetch_one(pool)
        .await?;
    let (nonce, ct) = value.split_at(super::crypto::NONCE_LEN.min(value.len()));
    match key.open(nonce, ct, NAME.as_bytes()) {
        Ok(p) if p == PLAIN => Ok(()),
        _ => anyhow::bail!("the master key does not match the one this database's data was sealed with"),
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
