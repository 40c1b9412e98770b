//! Installing a bundle: verifying the downloaded zip, extracting it into a staging directory, adding the
//! preview, and swapping it into `current/` (what `current/` held moves to `previous/`).

use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};

use super::error::{error_chain, io_err, ClientError};
use super::{CURRENT_DIR, PREVIEW_FILE, PREVIOUS_DIR};
use crate::service::routes::frames::FrameJob;
use eyekey_core::bundle::{self, MANIFEST_FILE, MAX_FILE_BYTES, MAX_MANIFEST_BYTES};
use eyekey_core::physics::observer::Observer;
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

/// One file copied out of the zip into the staging directory.
struct Extracted {
    name: String,
    sha256: String,
    bytes: u64,
}

/// Verifies the zip, extracts the manifest and the files it lists into a staging directory, adds the
/// preview, and swaps the staging directory into `current/`.
pub(super) fn install_bundle(
    zip_path: &Path,
    out_dir: &Path,
    job: &FrameJob,
    preview: Option<&VisionProfile>,
) -> Result<Installed, ClientError> {
    let (manifest, light_field) =
        bundle::read_bundle(zip_path).map_err(|source| ClientError::Bundle { job: job.id, source })?;
    let mut archive = reopen(zip_path, job)?;
    let staging = tempfile::Builder::new()
        .prefix(STAGING_PREFIX)
        .tempdir_in(out_dir)
        .map_err(io_err("create a staging directory in", out_dir))?;
    let extracted = extract(&mut archive, staging.path(), &manifest, job)?;
    check_against_listing(job, &extracted)?;
    let manifest_sha256 = extracted[0].sha256.clone();
    let preview_path = match preview {
        Some(profile) => {
            write_preview(staging.path(), &manifest, &light_field, profile)?;
            Some(out_dir.join(CURRENT_DIR).join(PREVIEW_FILE))
        }
        None => None,
    };
    sync_dir(staging.path())?;
    swap_into_current(staging, out_dir)?;
    Ok(Installed {
        frames: manifest.n_frames,
        manifest_sha256,
        preview: preview_path,
    })
}

type Archive = zip::ZipArchive<std::io::BufReader<std::fs::File>>;

/// Opens the zip [`bundle::read_bundle`] has verified again, to extract its files.
fn reopen(zip_path: &Path, job: &FrameJob) -> Result<Archive, ClientError> {
    let file = std::fs::File::open(zip_path).map_err(io_err("open", zip_path))?;
    zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| ClientError::Mismatch {
        job: job.id,
        reason: format!("the zip cannot be reopened: {e}"),
    })
}

/// Copies the manifest (first) and the files it lists from the zip into `staging`, each written and synced.
///
/// read_bundle has checked that every listed name is a plain file name and every file's checksum; the
/// copies are checked again as they are extracted.
fn extract(
    archive: &mut Archive,
    staging: &Path,
    manifest: &bundle::Manifest,
    job: &FrameJob,
) -> Result<Vec<Extracted>, ClientError> {
    let mismatch = |reason: String| ClientError::Mismatch { job: job.id, reason };
    let mut wanted: Vec<(&str, Option<&str>, u64)> = vec![(MANIFEST_FILE, None, MAX_MANIFEST_BYTES)];
    wanted.extend(
        manifest
            .files
            .iter()
            .map(|f| (f.name.as_str(), Some(f.sha256.as_str()), f.bytes.min(MAX_FILE_BYTES))),
    );
    let mut extracted = Vec::with_capacity(wanted.len());
    for (name, expected_sha, limit) in wanted {
        let mut bytes = Vec::new();
        archive
            .by_name(name)
            .map_err(|e| mismatch(format!("{name}: {e}")))?
            .take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| mismatch(format!("{name}: {e}")))?;
        let sha = bundle::sha256_hex(&bytes);
        if expected_sha.is_some_and(|s| !s.eq_ignore_ascii_case(&sha)) || bytes.len() as u64 > limit {
            return Err(mismatch(format!("{name} changed while it was being extracted")));
        }
        write_synced(&staging.join(name), &bytes)?;
        extracted.push(Extracted {
            name: name.to_string(),
            sha256: sha,
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

fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), ClientError> {
    let mut f = std::fs::File::create_new(path).map_err(io_err("create", path))?;
    f.write_all(bytes).map_err(io_err("write", path))?;
    f.sync_all().map_err(io_err("sync", path))
}

/// Makes a directory's entries durable (a rename is only safe once its directory is synced).
fn sync_dir(dir: &Path) -> Result<(), ClientError> {
    #[cfg(unix)]
    std::fs::File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(io_err("sync", dir))?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}
