//! Where sealed objects lie: uploaded documents and every file a job produces (frames, mask, manifest, the
//! bundle's zip, the evaluation report and views), each already sealed under its object's data key.
//!
//! With SQLite they are files under the data directory, as they always were. With PostgreSQL they are rows
//! of the `objects` table, so that every API process can serve what any worker produced, on any machine;
//! a job's outputs are inserted in one transaction, so a bundle is visible whole or not at all, as the
//! rename of a complete directory makes it on disk. Names are relative paths (`documents/<id>.sealed`,
//! `jobs/<job>-<attempt>/frame_0.png.sealed`) on both.

use std::io;
use std::path::{Path, PathBuf};

use super::{now_ms, Writer};

/// The store of sealed objects.
#[derive(Clone, Debug)]
pub enum Objects {
    /// Files under this directory (the data directory).
    Dir(PathBuf),
    /// Rows of the `objects` table (PostgreSQL).
    Database(Writer),
}

fn db_error(e: sqlx::Error) -> io::Error {
    if super::super::error::is_disk_full(&e) {
        return io::Error::new(io::ErrorKind::StorageFull, e);
    }
    io::Error::other(e)
}

/// The range of names under `dir/` (`/` + 1 is `0`), for a prefix match that needs no LIKE escaping.
fn range_under(dir: &str) -> (String, String) {
    let dir = dir.trim_end_matches('/');
    (format!("{dir}/"), format!("{dir}0"))
}

impl Objects {
    /// An object's sealed bytes; `None` when there is no such object.
    pub async fn read(&self, name: &str) -> io::Result<Option<Vec<u8>>> {
        match self {
            Self::Dir(root) => match tokio::fs::read(root.join(name)).await {
                Ok(b) => Ok(Some(b)),
                Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
                Err(e) => Err(e),
            },
            Self::Database(w) => {
                let row: Option<(Vec<u8>,)> = sqlx::query_as("SELECT data FROM objects WHERE path = $1")
                    .bind(name)
                    .fetch_optional(&w.0)
                    .await
                    .map_err(db_error)?;
                Ok(row.map(|(d,)| d))
            }
        }
    }

    /// Stores one object (replacing one of the same name). On disk: written beside, fsynced, renamed.
    pub async fn write(&self, name: &str, sealed: Vec<u8>) -> io::Result<()> {
        match self {
            Self::Dir(root) => {
                let path = root.join(name);
                tokio::task::spawn_blocking(move || {
                    if let Some(parent) = path.parent() {
                        std::fs::create_dir_all(parent)?;
                    }
                    crate::service::sealed::write_file(&path, &sealed)
                })
                .await
                .map_err(io::Error::other)?
            }
            Self::Database(w) => {
                sqlx::query(
                    "INSERT INTO objects (path, data, created_at) VALUES ($1, $2, $3)
                     ON CONFLICT (path) DO UPDATE SET data = excluded.data, created_at = excluded.created_at",
                )
                .bind(name)
                .bind(sealed)
                .bind(now_ms())
                .execute(&w.0)
                .await
                .map_err(db_error)?;
                Ok(())
            }
        }
    }

    /// Stores a directory of objects (`files`: names relative to `dir`) so that it becomes visible whole:
    /// on disk written into `.tmp-<dir's name>` beside it and renamed; in the database one transaction.
    /// Whatever stood under `dir` before (left by a crashed run of the same attempt) is replaced.
    pub async fn write_dir(&self, dir: &str, files: Vec<(String, Vec<u8>)>) -> io::Result<()> {
        match self {
            Self::Dir(root) => {
                let final_dir = root.join(dir);
                tokio::task::spawn_blocking(move || write_dir_on_disk(&final_dir, &files))
                    .await
                    .map_err(io::Error::other)?
            }
            Self::Database(w) => {
                let (from, to) = range_under(dir);
                let mut tx = w.0.begin().await.map_err(db_error)?;
                sqlx::query("DELETE FROM objects WHERE path >= $1 AND path < $2")
                    .bind(&from)
                    .bind(&to)
                    .execute(&mut *tx)
                    .await
                    .map_err(db_error)?;
                let now = now_ms();
                for (name, bytes) in files {
                    sqlx::query("INSERT INTO objects (path, data, created_at) VALUES ($1, $2, $3)")
                        .bind(format!("{from}{name}"))
                        .bind(bytes)
                        .bind(now)
                        .execute(&mut *tx)
                        .await
                        .map_err(db_error)?;
                }
                tx.commit().await.map_err(db_error)
            }
        }
    }

    /// Names (relative to `dir`) of the objects directly in `dir`, sorted.
    pub async fn list(&self, dir: &str) -> io::Result<Vec<String>> {
        match self {
            Self::Dir(root) => {
                let mut names = Vec::new();
                let mut entries = match tokio::fs::read_dir(root.join(dir)).await {
                    Ok(e) => e,
                    Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(names),
                    Err(e) => return Err(e),
                };
                while let Some(e) = entries.next_entry().await? {
                    if let Ok(name) = e.file_name().into_string() {
                        names.push(name);
                    }
                }
                names.sort();
                Ok(names)
            }
            Self::Database(w) => {
                let (from, to) = range_under(dir);
                let rows: Vec<(String,)> =
                    sqlx::query_as("SELECT path FROM objects WHERE path >= $1 AND path < $2 ORDER BY path")
                        .bind(&from)
                        .bind(&to)
                        .fetch_all(&w.0)
                        .await
                        .map_err(db_error)?;
                Ok(rows
                    .into_iter()
                    .filter_map(|(p,)| p.strip_prefix(&from).map(str::to_string))
                    .filter(|rest| !rest.contains('/'))
                    .collect())
            }
        }
    }

    /// Removes an object, or a directory and everything under it. Nothing there is not an error.
    pub async fn remove(&self, name: &str) -> io::Result<()> {
        match self {
            Self::Dir(root) => {
                let full = root.join(name);
                match tokio::fs::symlink_metadata(&full).await {
                    Ok(m) if m.is_dir() => tokio::fs::remove_dir_all(&full).await,
                    Ok(_) => tokio::fs::remove_file(&full).await,
                    Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
                    Err(e) => Err(e),
                }
            }
            Self::Database(w) => {
                let (from, to) = range_under(name);
                sqlx::query("DELETE FROM objects WHERE path = $1 OR (path >= $2 AND path < $3)")
                    .bind(name)
                    .bind(&from)
                    .bind(&to)
                    .execute(&w.0)
                    .await
                    .map_err(db_error)?;
                Ok(())
            }
        }
    }
}

/// Writes `files` into a temporary sibling of `final_dir`, then renames it into place (replacing an old
/// `final_dir`), syncing files and directories.
fn write_dir_on_disk(final_dir: &Path, files: &[(String, Vec<u8>)]) -> io::Result<()> {
    let parent = final_dir
        .parent()
        .ok_or_else(|| io::Error::other("an output directory needs a parent"))?;
    let name = final_dir
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| io::Error::other("an output directory needs a plain name"))?;
    std::fs::create_dir_all(parent)?;
    let tmp = parent.join(format!(".tmp-{name}"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    let written = (|| {
        for (file, bytes) in files {
            let path = tmp.join(file);
            if let Some(dir) = path.parent() {
                std::fs::create_dir_all(dir)?;
            }
            crate::service::sealed::write_file(&path, bytes)?;
        }
        if final_dir.exists() {
            std::fs::remove_dir_all(final_dir)?;
        }
        std::fs::rename(&tmp, final_dir)?;
        eyekey_core::bundle::fsync_dir(parent)
    })();
    if written.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_directory_is_written_whole_listed_read_and_removed_on_disk() {
        let root = tempfile::tempdir().unwrap();
        let objects = Objects::Dir(root.path().to_path_buf());
        let files = vec![
            ("a.png.sealed".to_string(), b"one".to_vec()),
            ("views/b.png.sealed".to_string(), b"two".to_vec()),
        ];
        objects.write_dir("jobs/j-1", files.clone()).await.unwrap();
        // A second write of the same attempt replaces the first whole.
        objects.write_dir("jobs/j-1", files[..1].to_vec()).await.unwrap();
        assert_eq!(objects.list("jobs/j-1").await.unwrap(), ["a.png.sealed"]);
        assert_eq!(objects.read("jobs/j-1/a.png.sealed").await.unwrap().unwrap(), b"one");
        assert_eq!(objects.read("jobs/j-1/views/b.png.sealed").await.unwrap(), None);
        let left: Vec<_> = std::fs::read_dir(root.path().join("jobs"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, ["j-1"], "no temporary directory left");
        objects.remove("jobs/j-1").await.unwrap();
        objects.remove("jobs/j-1").await.unwrap();
        assert_eq!(objects.list("jobs/j-1").await.unwrap(), Vec::<String>::new());
    }

    #[test]
    fn the_range_under_a_directory_holds_its_files_and_not_its_neighbours() {
        let (from, to) = range_under("jobs/j-1");
        let inside = |p: &str| p >= from.as_str() && p < to.as_str();
        assert!(inside("jobs/j-1/a") && inside("jobs/j-1/views/b"));
        assert!(!inside("jobs/j-1") && !inside("jobs/j-10/a") && !inside("jobs/j-1.x") && !inside("jobs/j-2/a"));
    }
}
