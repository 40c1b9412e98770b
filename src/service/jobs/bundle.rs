//! Frame bundles: which files of a job's output a display may fetch, and the zip that carries them.
//!
//! A job's output directory holds the bundle (`frame_<n>.png`, `barrier_mask.png`, `manifest.json`) and
//! operator-only files (`report.json`, `views/`), which may reveal profile-derived data. Only bundle
//! files are listed, zipped and served to displays.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Write as _};
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Name of the zip of the bundle inside a job's output directory.
pub const ZIP_NAME: &str = "bundle.zip";

/// One file of a bundle.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BundleFile {
    /// File name, e.g. `frame_0.png`.
    pub name: String,
    /// Size, bytes.
    pub bytes: u64,
    /// SHA-256 of the contents, hex.
    pub sha256: String,
}

/// True for the files a display client may fetch.
pub fn is_bundle_file(name: &str) -> bool {
    if name == "barrier_mask.png" || name == "manifest.json" {
        return true;
    }
    name.strip_prefix("frame_")
        .and_then(|rest| rest.strip_suffix(".png"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// True for names that are safe to join to a directory (no separators, no parent references).
pub fn is_plain_file_name(name: &str) -> bool {
    !name.is_empty()
        && name != "."
        && name != ".."
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
}

fn sort_key(name: &str) -> (u8, u64, String) {
    match name
        .strip_prefix("frame_")
        .and_then(|r| r.strip_suffix(".png"))
        .and_then(|n| n.parse().ok())
    {
        Some(n) => (0, n, String::new()),
        None => (1, 0, name.to_string()),
    }
}

fn sha256_file(path: &Path) -> io::Result<(u64, String)> {
    let mut hasher = Sha256::new();
    let n = io::copy(&mut BufReader::new(File::open(path)?), &mut hasher)?;
    Ok((n, hex::encode(hasher.finalize())))
}

/// Lists and hashes the bundle files in `dir` (frames in numeric order), then writes `bundle.zip` with
/// them; the zip is written under a temporary name and renamed, so it exists only when complete.
pub fn seal_bundle(dir: &Path) -> io::Result<Vec<BundleFile>> {
    let mut names: Vec<String> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| is_bundle_file(n))
        .collect();
    names.sort_by_key(|n| sort_key(n));
    if !names.iter().any(|n| n.starts_with("frame_")) {
        return Err(io::Error::other("the encoder wrote no frame_<n>.png"));
    }
    let mut files = Vec::with_capacity(names.len());
    for name in names {
        let (bytes, sha256) = sha256_file(&dir.join(&name))?;
        files.push(BundleFile { name, bytes, sha256 });
    }
    let part = dir.join(format!("{ZIP_NAME}.part"));
    let mut zip = zip::ZipWriter::new(BufWriter::new(File::create(&part)?));
    for f in &files {
        // PNGs are already deflated; storing them keeps the zip fast to write and to read.
        let method = if f.name.ends_with(".png") {
            zip::CompressionMethod::Stored
        } else {
            zip::CompressionMethod::Deflated
        };
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(method)
            .large_file(f.bytes >= u32::MAX as u64);
        zip.start_file(f.name.as_str(), options).map_err(io::Error::other)?;
        io::copy(&mut BufReader::new(File::open(dir.join(&f.name))?), &mut zip)?;
    }
    let mut inner = zip.finish().map_err(io::Error::other)?;
    inner.flush()?;
    inner.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    std::fs::rename(&part, dir.join(ZIP_NAME))?;
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_frames_mask_and_manifest_are_bundle_files() {
        for ok in ["frame_0.png", "frame_12.png", "barrier_mask.png", "manifest.json"] {
            assert!(is_bundle_file(ok), "{ok}");
        }
        for no in [
            "report.json",
            "views",
            "frame_.png",
            "frame_a.png",
            "frame_1.png.bak",
            "bundle.zip",
        ] {
            assert!(!is_bundle_file(no), "{no}");
        }
        assert!(!is_plain_file_name("../x") && !is_plain_file_name("a/b") && !is_plain_file_name(".."));
    }

    #[test]
    fn sealing_zips_bundle_files_in_frame_order_and_leaves_the_rest_out() {
        let dir = tempfile::tempdir().unwrap();
        for name in [
            "frame_10.png",
            "frame_2.png",
            "barrier_mask.png",
            "manifest.json",
            "report.json",
        ] {
            std::fs::write(dir.path().join(name), name.as_bytes()).unwrap();
        }
        let files = seal_bundle(dir.path()).unwrap();
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            ["frame_2.png", "frame_10.png", "barrier_mask.png", "manifest.json"]
        );
        let zip = zip::ZipArchive::new(File::open(dir.path().join(ZIP_NAME)).unwrap()).unwrap();
        assert_eq!(zip.len(), 4);
        assert!(zip.index_for_name("report.json").is_none());
        assert_eq!(files[0].sha256, hex::encode(Sha256::digest(b"frame_2.png")));
    }
}
