//! Why a bundle could not be written, read or zipped.

use crate::bundle::MANIFEST_FILE;
use std::path::{Path, PathBuf};

/// Why a bundle could not be written, read or zipped. Every message names the file and the problem.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BundleError {
    /// A file system operation failed.
    #[error("cannot {op} {}", path.display())]
    Io {
        /// What was being done ("read", "create", "rename", ...).
        op: &'static str,
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A PNG could not be encoded or decoded.
    #[error("{name}: not a readable PNG ({reason})")]
    Png {
        /// The file.
        name: String,
        /// Encoder or decoder message.
        reason: String,
    },
    /// A file's SHA-256 differs from the manifest's.
    #[error("{name}: SHA-256 is {actual} but the manifest says {expected}; the file is corrupt or was changed")]
    Checksum {
        /// The file.
        name: String,
        /// SHA-256 in the manifest.
        expected: String,
        /// SHA-256 of the file.
        actual: String,
    },
    /// A file's size differs from the manifest's.
    #[error("{name}: {actual} bytes but the manifest says {expected}; the file is truncated or was changed")]
    Size {
        /// The file.
        name: String,
        /// Size in the manifest.
        expected: u64,
        /// Size of the file (at most one byte past `expected`: reading stops there).
        actual: u64,
    },
    /// The display, the frames and the mask do not fit together.
    #[error("geometry: {reason}")]
    Geometry {
        /// What does not fit, naming the file or field.
        reason: String,
    },
    /// A file the manifest lists is not in the bundle.
    #[error("{name} is listed in the manifest but is not in the bundle")]
    Missing {
        /// The file.
        name: String,
    },
    /// The manifest is unreadable or inconsistent.
    #[error("{MANIFEST_FILE}: {reason}")]
    Manifest {
        /// What is wrong.
        reason: String,
    },
    /// The zip archive is unreadable or could not be written.
    #[error("zip archive: {reason}")]
    Zip {
        /// What is wrong.
        reason: String,
    },
    /// A file name that is not a plain name inside the bundle directory.
    #[error("{name:?} is not a plain file name (no '/', '\\', ':', '..', control characters or leading '.')")]
    UnsafeName { name: String },
    /// A file name used twice, or one that clashes with a name the bundle reserves.
    #[error("{name:?} appears twice in the bundle or clashes with a file the bundle writes itself")]
    DuplicateName { name: String },
    /// A file is larger than the reader accepts.
    #[error("{name}: larger than the limit of {limit} bytes")]
    TooLarge {
        /// The file (or "bundle" for the total).
        name: String,
        /// The limit, bytes.
        limit: u64,
    },
    /// The light field does not fit the display.
    #[error("light field: {reason}")]
    LightField {
        /// What is wrong.
        reason: String,
    },
    /// The output directory already exists with something in it.
    #[error("{}: already exists and is not an empty directory; refusing to overwrite it", path.display())]
    NotEmpty {
        /// The directory.
        path: PathBuf,
    },
}

pub(crate) fn io_err<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> BundleError + 'a {
    move |source| BundleError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn geometry(reason: String) -> BundleError {
    BundleError::Geometry { reason }
}

/// Accepts only names that stay inside the bundle directory on every platform and are not hidden.
pub(crate) fn check_plain_name(name: &str) -> Result<(), BundleError> {
    let unsafe_name = name.is_empty()
        || name.starts_with('.')
        || name.contains("..")
        || name.chars().any(|c| matches!(c, '/' | '\\' | ':') || c.is_control());
    if unsafe_name {
        Err(BundleError::UnsafeName { name: name.to_string() })
    } else {
        Ok(())
    }
}
