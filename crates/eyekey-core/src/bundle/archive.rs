//! Zipping a bundle for download.

use crate::bundle::{read_manifest, BundleError, Source, MANIFEST_FILE};
use std::io::{Seek, Write};
use std::path::Path;

/// Zips the bundle directory `dir` into `out` for download: `manifest.json` first, then the files it lists
/// in the manifest's order, nothing else. Each file's size and SHA-256 are checked on the way, so a damaged
/// bundle is not shipped. The archive is reproducible: fixed timestamps (1980-01-01) and permissions, PNGs
/// stored (already compressed), other files deflated.
pub fn zip_bundle<W: Write + Seek>(dir: &Path, out: W) -> Result<(), BundleError> {
    let mut source = Source::Dir(dir.to_path_buf());
    let (manifest_bytes, manifest, _) = read_manifest(&mut source)?;

    let zip_err = |e: zip::result::ZipError| BundleError::Zip { reason: e.to_string() };
    let options = zip::write::SimpleFileOptions::default()
        .last_modified_time(zip::DateTime::default())
        .unix_permissions(0o644);
    let mut writer = zip::ZipWriter::new(out);
    writer
        .start_file(
            MANIFEST_FILE,
            options.compression_method(zip::CompressionMethod::Deflated),
        )
        .map_err(zip_err)?;
    writer.write_all(&manifest_bytes).map_err(|e| BundleError::Zip {
        reason: format!("{MANIFEST_FILE}: {e}"),
    })?;
    for entry in &manifest.files {
        let bytes = source.read_verified(entry)?;
        let method = if entry.name.ends_with(".png") {
            zip::CompressionMethod::Stored
        } else {
            zip::CompressionMethod::Deflated
        };
        writer
            .start_file(entry.name.as_str(), options.compression_method(method))
            .map_err(zip_err)?;
        writer.write_all(&bytes).map_err(|e| BundleError::Zip {
            reason: format!("{}: {e}", entry.name),
        })?;
    }
    writer.finish().map_err(zip_err)?;
    Ok(())
}
