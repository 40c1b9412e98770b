//! Atomic directories: write into a hidden sibling, fsync, rename.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

#[allow(unused_imports)]
use super::*;

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
    let mut f = fs::File::create_new(path).map_err(io_err("create", path))?;
    f.write_all(bytes).map_err(io_err("write", path))?;
    f.sync_all().map_err(io_err("sync", path))
}

/// Makes a directory's entries durable (a rename or a new file is only safe once its directory is synced).
pub(crate) fn sync_dir(dir: &Path) -> Result<(), BundleError> {
    #[cfg(unix)]
    {
        fs::File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(io_err("sync", dir))?;
    }
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}
