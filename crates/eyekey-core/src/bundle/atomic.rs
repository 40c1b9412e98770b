//! Atomic directories: write into a hidden sibling, fsync, rename.

use crate::bundle::{io_err, BundleError};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// `dir` must be absent or an empty directory.
pub(crate) fn check_target_dir(dir: &Path) -> Result<(), BundleError> {
    match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(source) => Err(BundleError::Io {
            op: "inspect",
            path: dir.to_path_buf(),
            source,
        }),
        Ok(m) if m.is_dir() => {
            let mut entries = fs::read_dir(dir).map_err(io_err("list", dir))?;
            if entries.next().is_none() {
                Ok(())
            } else {
                Err(BundleError::NotEmpty {
                    path: dir.to_path_buf(),
                })
            }
        }
        Ok(_) => Err(BundleError::NotEmpty {
            path: dir.to_path_buf(),
        }),
    }
}

/// The parent directory of `dir` (`.` for a bare name) and `dir`'s last component.
pub(crate) fn split_dir(dir: &Path) -> Result<(PathBuf, String), BundleError> {
    let base = dir
        .file_name()
        .map(|b| b.to_string_lossy().into_owned())
        .ok_or_else(|| BundleError::UnsafeName {
            name: dir.display().to_string(),
        })?;
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok((parent, base))
}

pub(crate) fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), BundleError> {
    create_synced(path, bytes).map_err(io_err("write", path))
}

/// Creates `path` (which must not exist), writes `bytes` and fsyncs the file.
pub fn create_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = fs::File::create_new(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// Makes a directory's entries durable (a rename or a new file is only safe once its directory is synced).
/// A no-op where directories cannot be opened for syncing (not Unix).
pub fn fsync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    fs::File::open(dir)?.sync_all()?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

pub(crate) fn sync_dir(dir: &Path) -> Result<(), BundleError> {
    fsync_dir(dir).map_err(io_err("sync", dir))
}

/// Writes `contents` (name, bytes, ...) as the files of directory `dir`, atomically: everything is written
/// and fsynced into a fresh hidden sibling (`.<name>.tmp-<random>`), which is then renamed to `dir`. `dir`
/// must be absent or empty. On any error the temporary directory is removed.
pub(crate) fn write_dir_atomically<R>(dir: &Path, contents: &[(String, Vec<u8>, R)]) -> Result<(), BundleError> {
    let (parent, base) = split_dir(dir)?;
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{base}.tmp-"))
        .tempdir_in(&parent)
        .map_err(io_err("create a temporary directory in", &parent))?;
    // From here on, returning early drops `tmp`, which removes it and everything in it.
    for (name, bytes, _) in contents {
        write_synced(&tmp.path().join(name), bytes)?;
    }
    sync_dir(tmp.path())?;
    fs::rename(tmp.path(), dir).map_err(|source| match source.kind() {
        // Someone filled `dir` after the check above.
        std::io::ErrorKind::DirectoryNotEmpty | std::io::ErrorKind::AlreadyExists => BundleError::NotEmpty {
            path: dir.to_path_buf(),
        },
        _ => BundleError::Io {
            op: "rename the temporary bundle to",
            path: dir.to_path_buf(),
            source,
        },
    })?;
    // The directory now lives at `dir`; stop `tmp` from trying to remove its old path.
    let _ = tmp.keep();
    // Best effort: the files are complete and in place; failing now would report an error for a directory
    // that exists (and a retry would then hit `NotEmpty`).
    let _ = sync_dir(&parent);
    Ok(())
}

/// Writes `files` (plain names, bytes) as the files of directory `dir`, atomically, as
/// [`crate::bundle::write_bundle`] does: `dir` must be absent or empty, and appears only when complete.
pub fn write_files_atomically(dir: &Path, files: &[(String, Vec<u8>)]) -> Result<(), BundleError> {
    check_target_dir(dir)?;
    for (name, _) in files {
        crate::bundle::check_plain_name(name)?;
    }
    let contents: Vec<(String, Vec<u8>, ())> = files.iter().map(|(n, b)| (n.clone(), b.clone(), ())).collect();
    write_dir_atomically(dir, &contents)
}
