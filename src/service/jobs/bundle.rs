//! Frame bundles: which files of a job's output a display may fetch, and the zip that carries them.
//!
//! A job's outputs are the bundle (`frame_<n>.png`, `barrier_mask.png`, `manifest.json`) and operator-only
//! files (`report.json`, `views/`), which show the document and may reveal profile-derived data. Only bundle
//! files are listed, zipped and served to displays. Every one of them is stored sealed
//! ([`crate::service::sealed`]).

use std::io::{self, Write as _};

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

/// The bundle files among a job's outputs (frames in numeric order, then the mask and the manifest),
/// listed with their sizes and SHA-256, and the zip that carries them, built in memory.
pub fn zip_bundle(outputs: &[(String, Vec<u8>)]) -> io::Result<(Vec<BundleFile>, Vec<u8>)> {
    let mut bundle: Vec<&(String, Vec<u8>)> = outputs.iter().filter(|(n, _)| is_bundle_file(n)).collect();
    bundle.sort_by_key(|(n, _)| sort_key(n));
    if !bundle.iter().any(|(n, _)| n.starts_with("frame_")) {
        return Err(io::Error::other("the encoder wrote no frame_<n>.png"));
    }
    let files: Vec<BundleFile> = bundle
        .iter()
        .map(|(name, bytes)| BundleFile {
            name: name.clone(),
            bytes: bytes.len() as u64,
            sha256: hex::encode(Sha256::digest(bytes)),
        })
        .collect();
    let mut zip = zip::ZipWriter::new(io::Cursor::new(Vec::new()));
    for (name, bytes) in &bundle {
        // PNGs are already deflated; storing them keeps the zip fast to write and to read.
        let method = if name.ends_with(".png") {
            zip::CompressionMethod::Stored
        } else {
            zip::CompressionMethod::Deflated
        };
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(method)
            .large_file(bytes.len() as u64 >= u32::MAX as u64);
        zip.start_file(name.as_str(), options).map_err(io::Error::other)?;
        zip.write_all(bytes)?;
    }
    let zipped = zip.finish().map_err(io::Error::other)?.into_inner();
    Ok((files, zipped))
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
    fn the_zip_carries_bundle_files_in_frame_order_and_leaves_the_rest_out() {
        let outputs: Vec<(String, Vec<u8>)> = [
            "frame_10.png",
            "frame_2.png",
            "barrier_mask.png",
            "manifest.json",
            "report.json",
            "views/target.png",
        ]
        .iter()
        .map(|n| (n.to_string(), n.as_bytes().to_vec()))
        .collect();
        let (files, zipped) = zip_bundle(&outputs).unwrap();
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            ["frame_2.png", "frame_10.png", "barrier_mask.png", "manifest.json"]
        );
        let mut zip = zip::ZipArchive::new(io::Cursor::new(zipped)).unwrap();
        assert_eq!(zip.len(), 4);
        assert!(zip.index_for_name("report.json").is_none());
        let mut frame = String::new();
        io::Read::read_to_string(&mut zip.by_name("frame_2.png").unwrap(), &mut frame).unwrap();
        assert_eq!(frame, "frame_2.png");
        assert_eq!(files[0].sha256, hex::encode(Sha256::digest(b"frame_2.png")));
        assert_eq!(files[0].bytes, 11);
        assert!(zip_bundle(&outputs[2..4]).is_err(), "a bundle without frames");
    }
}
