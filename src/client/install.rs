//! Installing a bundle: verifying the downloaded zip, writing its verified files into a staging directory,
//! adding the preview, and swapping it into `current/` (what `current/` held moves to `previous/`).

use std::path::{Path, PathBuf};

use super::error::{error_chain, io_err, ClientError};
use super::{CURRENT_DIR, PREVIEW_FILE, PREVIOUS_DIR};
use crate::service::routes::frames::FrameJob;
use eyekey_core::bundle::{self, MANIFEST_FILE};
use eyekey_core::physics::observer::{Observer, Optics};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportOptions};

/// Prefixes of the client's own temporary entries in the output directory, removed at start-up.
pub(super) const DOWNLOAD_PREFIX: &str = ".download-";
const STAGING_PREFIX: &str = ".incoming-";

/// Creates the output directory and removes temporary entries an interrupted run left behind. Call it once
/// at start-up, before the first sync, not while another client may use the same directory.
pub fn prepare_out_dir(out_dir: &Path) -> Result<(), ClientError> {
    std::fs::create_dir_all(out_dir).map_err(io_err("create", out_dir))?;
    let entries = std::fs::read_dir(out_dir).map_err(io_err("list", out_dir))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with(DOWNLOAD_PREFIX) || name.starts_with(STAGING_PREFIX) || name.starts_with(".state-")) {
            continue;
        }
        let path = entry.path();
        let removed = if entry.file_type().is_ok_and(|t| t.is_dir()) {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if let Err(e) = removed {
            tracing::warn!(path = %path.display(), error = %e, "cannot remove a leftover temporary entry");
        }
    }
    Ok(())
}

/// What [`install_bundle`] put into `current/`.
pub(super) struct Installed {
    pub(super) frames: u32,
    pub(super) manifest_sha256: String,
    pub(super) preview: Option<PathBuf>,
}

/// One verified file written into the staging directory.
struct Extracted {
    name: String,
    sha256: String,
    bytes: u64,
}

/// Verifies the zip, writes the manifest and the files it lists (as verified) into a staging directory, adds
/// the preview, and swaps the staging directory into `current/`.
pub(super) fn install_bundle(
    zip_path: &Path,
    out_dir: &Path,
    job: &FrameJob,
    preview: Option<&VisionProfile>,
) -> Result<Installed, ClientError> {
    let verified =
        bundle::read_verified_bundle(zip_path).map_err(|source| ClientError::Bundle { job: job.id, source })?;
    let staging = tempfile::Builder::new()
        .prefix(STAGING_PREFIX)
        .tempdir_in(out_dir)
        .map_err(io_err("create a staging directory in", out_dir))?;
    let extracted = write_files(staging.path(), &verified)?;
    check_against_listing(job, &extracted)?;
    let manifest_sha256 = extracted[0].sha256.clone();
    let preview_path = match preview {
        Some(profile) => {
            write_preview(staging.path(), &verified.manifest, &verified.light_field, profile)?;
            Some(out_dir.join(CURRENT_DIR).join(PREVIEW_FILE))
        }
        None => None,
    };
    sync_dir(staging.path())?;
    swap_into_current(staging, out_dir)?;
    Ok(Installed {
        frames: verified.manifest.n_frames,
        manifest_sha256,
        preview: preview_path,
    })
}

/// Writes the manifest (first) and the files it lists into `staging`, each written and synced.
///
/// read_verified_bundle has checked that every listed name is a plain file name and every file's size and
/// checksum; the bytes written are the ones it verified.
fn write_files(staging: &Path, verified: &bundle::VerifiedBundle) -> Result<Vec<Extracted>, ClientError> {
    let files = std::iter::once((MANIFEST_FILE, verified.manifest_bytes.as_slice())).chain(
        verified
            .files
            .iter()
            .map(|(name, bytes)| (name.as_str(), bytes.as_slice())),
    );
    let mut extracted = Vec::with_capacity(1 + verified.files.len());
    for (name, bytes) in files {
        write_synced(&staging.join(name), bytes)?;
        extracted.push(Extracted {
            name: name.to_string(),
            sha256: bundle::sha256_hex(bytes),
            bytes: bytes.len() as u64,
        });
    }
    Ok(extracted)
}

/// Checks that every file the server lists for the job was extracted, with the listed checksum and size.
fn check_against_listing(job: &FrameJob, extracted: &[Extracted]) -> Result<(), ClientError> {
    let mismatch = |reason: String| ClientError::Mismatch { job: job.id, reason };
    for listed in &job.files {
        match extracted.iter().find(|e| e.name == listed.name) {
            Some(e) if e.sha256.eq_ignore_ascii_case(&listed.sha256) && e.bytes == listed.bytes => {}
            Some(_) => {
                return Err(mismatch(format!(
                    "{} differs from the checksum and size the server lists",
                    listed.name
                )))
            }
            None => {
                return Err(mismatch(format!(
                    "the server lists {} but the bundle does not hold it",
                    listed.name
                )))
            }
        }
    }
    Ok(())
}

/// Simulates what the person with `profile` sees of the light field and writes it to `staging/preview.png`.
fn write_preview(
    staging: &Path,
    manifest: &bundle::Manifest,
    light_field: &[f32],
    profile: &VisionProfile,
) -> Result<(), ClientError> {
    let options = TransportOptions {
        sub_rays: 16,
        retina_oversample: 2,
        ..Default::default()
    };
    let observer = Observer::new(
        &manifest.display,
        profile,
        EyePosition::default(),
        &options,
        // The physics a real eye sees through, whatever model the frames were encoded under: the manifest does
        // not say (it carries nothing of the encoder), and the preview should not flatter them.
        Optics::Wave,
        &eyekey_core::physics::transport::TransportCache::disabled(),
    )
    .map_err(|e| ClientError::Preview(e.to_string()))?;
    let picture = observer.picture(&observer.view(light_field));
    eyekey_core::imaging::save_rgb_png(&picture, &staging.join(PREVIEW_FILE))
        .map_err(|e| ClientError::Preview(error_chain(&e)))
}

/// The swap: `previous` is dropped, `current` becomes `previous`, the staging directory becomes `current`.
fn swap_into_current(staging: tempfile::TempDir, out_dir: &Path) -> Result<(), ClientError> {
    let current = out_dir.join(CURRENT_DIR);
    let previous = out_dir.join(PREVIOUS_DIR);
    if previous.exists() {
        std::fs::remove_dir_all(&previous).map_err(io_err("remove", &previous))?;
    }
    if current.exists() {
        std::fs::rename(&current, &previous).map_err(io_err("move aside", &current))?;
    }
    std::fs::rename(staging.path(), &current).map_err(io_err("rename the staging directory to", &current))?;
    // The directory now lives at `current`; stop the guard from removing its old path.
    let _ = staging.keep();
    sync_dir(out_dir)
}

/// Creates `path`, writes `bytes` and fsyncs the file.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), ClientError> {
    bundle::create_synced(path, bytes).map_err(io_err("write", path))
}

/// Makes a directory's entries durable (a rename is only safe once its directory is synced).
fn sync_dir(dir: &Path) -> Result<(), ClientError> {
    bundle::fsync_dir(dir).map_err(io_err("sync", dir))
}
