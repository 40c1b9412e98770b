//! The frame bundle: what an encode hands to the display.
//!
//! A bundle is a directory, or a `.zip` of one, holding
//! - one 16-bit greyscale PNG per projector, `frame_<n>.png`, of (X·U)×(Y·V) pixels with
//!   pixel (x·U+i, y·V+j) = round(L(x, y, i, j, n)/L_max·65535) (docs/design.md §2);
//! - the barrier mask, `barrier_mask.png`, 8-bit grey, 255 = open ([`DisplayGeometry::barrier_mask`]);
//! - any extra files the caller adds (an evaluation report, say);
//! - `manifest.json` ([`Manifest`]): format version, display geometry with its projector spectra and L_max,
//!   the frames' size and number, the mask's resolution, and the SHA-256 and size of every other file: what a
//!   display needs to show the frames, nothing more. Never the encoder's options or seed, the solver's record
//!   or the target's profile label (an operator's, in `encoding.json` beside the bundle), and never anything of
//!   the document itself: not its text, not a hash of it (a hash of a PIN slip is the PIN, to anyone who can
//!   render the ten thousand candidates).
//!
//! The checksums catch corruption and accidental edits, not forgery: whoever can rewrite the files can
//! rewrite the manifest too.
//!
//! Writing is atomic: everything goes into a hidden temporary sibling directory that is renamed into place
//! only once every file is on disk, so nobody ever sees a partial bundle. Reading verifies sizes, checksums
//! and geometry before it returns a light field, and treats a zip as hostile: it reads only the plain file
//! names the manifest lists, never extracts anything to disk, and caps how much it inflates.

mod archive;
mod atomic;
mod error;
mod manifest;
mod read;
mod write;

pub use archive::*;
use atomic::*;
pub use atomic::{create_synced, fsync_dir, write_files_atomically};
pub use error::*;
pub use manifest::*;
pub use read::*;
pub use write::*;

use sha2::{Digest, Sha256};

/// Version of the bundle layout written by [`write_bundle`]; [`read_bundle`] also reads version 1, whose manifest
/// recorded the encoder too (ignored).
pub const FORMAT_VERSION: u32 = 2;

/// Name of the manifest inside a bundle.
pub const MANIFEST_FILE: &str = "manifest.json";

/// Name of the barrier-mask PNG inside a bundle.
pub const MASK_FILE: &str = "barrier_mask.png";

/// Largest `manifest.json` the reader accepts, bytes.
pub const MAX_MANIFEST_BYTES: u64 = 16 << 20;

/// Largest single listed file, bytes. The largest valid display (64 M samples in one band) makes a frame of
/// about 128 MiB, so this leaves room while bounding what a hostile zip can make the reader inflate.
pub const MAX_FILE_BYTES: u64 = 512 << 20;

/// Largest total of all listed files, bytes.
pub const MAX_BUNDLE_BYTES: u64 = 2 << 30;

/// Largest barrier-mask resolution, pixels per hole pitch.
pub const MAX_MASK_PIXELS_PER_HOLE: u32 = 64;

/// Largest barrier mask, pixels (the same bound as the light field's unknowns).
const MAX_MASK_PIXELS: u64 = 64_000_000;

/// File name of projector `n`'s frame: `frame_0.png`, `frame_1.png`, ...
pub fn frame_file_name(n: usize) -> String {
    format!("frame_{n}.png")
}

/// Lower-case hex SHA-256 of `bytes`, as recorded in the manifest.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::fs;
    use std::io::{Cursor, Write};
    use std::path::Path;

    use image::DynamicImage;

    use crate::physics::display::DisplayGeometry;

    use rand::{Rng, SeedableRng};

    fn small_display() -> DisplayGeometry {
        DisplayGeometry {
            aperture: Default::default(),
            holes_x: 6,
            holes_y: 4,
            l_max: 2.0,
            ..DisplayGeometry::paper()
        }
    }

    fn random_field(d: &DisplayGeometry, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..d.n_samples_per_band() * d.n_bands())
            .map(|_| rng.gen_range(0.0..=d.l_max as f32))
            .collect()
    }

    fn write_small(dir: &Path) -> (DisplayGeometry, Vec<f32>, Manifest) {
        let d = small_display();
        let l = random_field(&d, 7);
        let extra = vec![("report.json".to_string(), b"{}".to_vec())];
        let m = write_bundle(dir, &d, &l, &extra, 4).unwrap();
        (d, l, m)
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    fn assert_close(a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len());
        for (k, (x, y)) in a.iter().zip(b).enumerate() {
            assert!((x - y).abs() <= tol, "value {k}: {x} vs {y}");
        }
    }

    fn rewrite_manifest(dir: &Path, edit: impl FnOnce(&mut Manifest)) {
        let path = dir.join(MANIFEST_FILE);
        let mut m: Manifest = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
        edit(&mut m);
        fs::write(path, serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    }

    #[test]
    fn a_verified_read_returns_every_file_as_it_is_on_disk() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("b");
        let (_, l, m) = write_small(&dir);
        let v = read_verified_bundle(&dir).unwrap();
        assert_eq!(v.manifest, m);
        assert_eq!(v.light_field.len(), l.len());
        assert_eq!(v.manifest_bytes, fs::read(dir.join(MANIFEST_FILE)).unwrap());
        let names: Vec<&str> = v.files.iter().map(|(n, _)| n.as_str()).collect();
        let listed: Vec<&str> = m.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, listed);
        for (name, bytes) in &v.files {
            assert_eq!(bytes, &fs::read(dir.join(name)).unwrap(), "{name}");
        }
    }

    #[test]
    fn write_then_read_gives_back_the_light_field_to_quantisation() {
        // 16-bit quantisation rounds L/L_max·65535, so values come back within 1/65535·L_max (l_max = 2
        // checks the scaling both ways).
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        let (d, l, written) = write_small(&dir);
        assert_eq!(entries(root.path()), vec!["bundle"]);
        assert_eq!(
            entries(&dir),
            vec![
                "barrier_mask.png",
                "frame_0.png",
                "frame_1.png",
                "frame_2.png",
                "frame_3.png",
                "manifest.json",
                "report.json"
            ]
        );
        assert_eq!(
            (written.frame_width, written.frame_height, written.n_frames),
            (30, 20, 4)
        );
        assert_eq!(written.files.len(), d.n_bands() + 2);
        let (read, back) = read_bundle(&dir).unwrap();
        assert_eq!(read, written);
        assert_close(&back, &l, (d.l_max / 65535.0) as f32);
    }

    #[test]
    fn frames_put_each_sample_at_its_documented_pixel() {
        // docs/design.md §2: pixel (x·U+i, y·V+j) of frame n is L(x, y, i, j, n)/L_max.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("b");
        let (d, l, _) = write_small(&dir);
        let frame = image::open(dir.join(frame_file_name(2))).unwrap().into_luma16();
        let (x, y, i, j) = (5, 3, 1, 4);
        let p = d.sample_index(x, y, i, j);
        let v = frame.get_pixel(x * d.views_u + i, y * d.views_v + j)[0];
        assert_eq!(v, (l[p * d.n_bands() + 2] as f64 / d.l_max * 65535.0).round() as u16);
    }

    #[test]
    fn zip_round_trip_gives_back_the_same_bundle() {
        // The downloaded zip must read exactly like the directory it came from.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        let (d, l, written) = write_small(&dir);
        let zip_path = root.path().join("bundle.zip");
        zip_bundle(&dir, fs::File::create(&zip_path).unwrap()).unwrap();
        let (read, back) = read_bundle(&zip_path).unwrap();
        assert_eq!(read, written);
        assert_close(&back, &l, (d.l_max / 65535.0) as f32);
        // Deterministic: zipping again gives the same bytes.
        let mut again = Cursor::new(Vec::new());
        zip_bundle(&dir, &mut again).unwrap();
        assert_eq!(again.into_inner(), fs::read(&zip_path).unwrap());
    }

    #[test]
    fn a_flipped_byte_in_a_frame_is_a_checksum_error_naming_the_file() {
        // Corruption must be caught before the frame is decoded or shown.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        let path = dir.join("frame_1.png");
        let mut bytes = fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x01;
        fs::write(&path, bytes).unwrap();
        let err = read_bundle(&dir).unwrap_err();
        assert!(
            matches!(&err, BundleError::Checksum { name, .. } if name == "frame_1.png"),
            "{err}"
        );
        assert!(err.to_string().contains("frame_1.png"), "{err}");
    }

    #[test]
    fn a_manifest_display_with_other_holes_is_a_geometry_error() {
        // Frames made for one barrier must not be shown on another.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        rewrite_manifest(&dir, |m| m.display.holes_x = 7);
        let err = read_bundle(&dir).unwrap_err();
        assert!(matches!(err, BundleError::Geometry { .. }), "{err}");
    }

    #[test]
    fn a_manifest_that_carries_more_than_the_display_needs_is_refused_but_the_first_layout_is_still_read() {
        // A bundle of the first layout (which recorded the encoder's options, seed included) is still read, the
        // record ignored; one of an unknown version is refused, and one of this version with an extra field, for
        // the field.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        let path = dir.join(MANIFEST_FILE);
        let edit = |f: &dyn Fn(&mut serde_json::Map<String, serde_json::Value>)| {
            let mut m: serde_json::Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
            f(m.as_object_mut().unwrap());
            fs::write(&path, serde_json::to_vec_pretty(&m).unwrap()).unwrap();
        };
        let pristine = fs::read(&path).unwrap();
        edit(&|m| {
            m.insert("format_version".into(), 1.into());
            m.insert("created_at".into(), "2026-12-01T00:00:00Z".into());
            m.insert("profile_label".into(), "alice@3".into());
            m.insert("encoder".into(), serde_json::json!({ "seed": 1 }));
            m.insert("solver".into(), serde_json::json!({ "iterations": 12 }));
        });
        let (old, _) = read_bundle(&dir).unwrap();
        assert_eq!(old.format_version, 1);
        edit(&|m| {
            m.insert("format_version".into(), 3.into());
        });
        let err = read_bundle(&dir).unwrap_err().to_string();
        assert!(err.contains("format version 3 is not supported"), "{err}");
        fs::write(&path, &pristine).unwrap();
        edit(&|m| {
            m.insert("encoder".into(), serde_json::json!({ "seed": 1 }));
        });
        let err = read_bundle(&dir).unwrap_err().to_string();
        assert!(err.contains("unknown field `encoder`"), "{err}");
        fs::write(&path, &pristine).unwrap();
        assert!(read_bundle(&dir).is_ok());
    }

    #[test]
    fn a_frame_of_the_wrong_size_is_a_geometry_error_even_with_a_matching_checksum() {
        // The checksum only proves the file is the one listed; its pixels must still fit the display.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        let wrong = encode_png(
            "frame_0.png",
            &DynamicImage::ImageLuma16(image::ImageBuffer::new(31, 20)),
        )
        .unwrap();
        fs::write(dir.join("frame_0.png"), &wrong).unwrap();
        rewrite_manifest(&dir, |m| {
            let e = m.files.iter_mut().find(|e| e.name == "frame_0.png").unwrap();
            e.sha256 = sha256_hex(&wrong);
            e.bytes = wrong.len() as u64;
        });
        let err = read_bundle(&dir).unwrap_err();
        assert!(matches!(err, BundleError::Geometry { .. }), "{err}");
        assert!(err.to_string().contains("frame_0.png"), "{err}");
    }

    #[test]
    fn writing_into_a_non_empty_directory_fails_and_changes_nothing() {
        // Never overwrite or mix into someone's files.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        fs::create_dir(&dir).unwrap();
        fs::write(dir.join("keep.txt"), b"mine").unwrap();
        let d = small_display();
        let err = write_bundle(&dir, &d, &random_field(&d, 1), &[], 4).unwrap_err();
        assert!(matches!(err, BundleError::NotEmpty { .. }), "{err}");
        assert_eq!(entries(root.path()), vec!["bundle"]);
        assert_eq!(entries(&dir), vec!["keep.txt"]);
        assert_eq!(fs::read(dir.join("keep.txt")).unwrap(), b"mine");
    }

    #[test]
    fn writing_into_an_existing_empty_directory_succeeds() {
        // An empty directory made ahead (by a job runner, say) is an acceptable target.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        fs::create_dir(&dir).unwrap();
        write_small(&dir);
        read_bundle(&dir).unwrap();
        assert_eq!(entries(root.path()), vec!["bundle"]);
    }

    #[test]
    fn a_failed_write_leaves_neither_a_temporary_directory_nor_the_bundle() {
        // "../x" is refused up front; a 300-byte name passes the check but fails at the file system after
        // the frames are on disk, which exercises the clean-up of the temporary directory.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        let d = small_display();
        let l = random_field(&d, 2);
        let traversal = vec![("../x".to_string(), b"x".to_vec())];
        let err = write_bundle(&dir, &d, &l, &traversal, 4).unwrap_err();
        assert!(matches!(err, BundleError::UnsafeName { .. }), "{err}");
        assert!(entries(root.path()).is_empty());
        let too_long = vec![("r".repeat(300), b"x".to_vec())];
        let err = write_bundle(&dir, &d, &l, &too_long, 4).unwrap_err();
        assert!(matches!(err, BundleError::Io { .. }), "{err}");
        assert!(entries(root.path()).is_empty(), "{:?}", entries(root.path()));
        assert!(!root.path().join("x").exists());
    }

    #[test]
    fn a_light_field_of_the_wrong_length_is_refused() {
        // One band short must not be written as a bundle of garbage frames.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        let d = small_display();
        let mut l = random_field(&d, 3);
        l.truncate(l.len() - d.n_samples_per_band());
        let err = write_bundle(&dir, &d, &l, &[], 4).unwrap_err();
        assert!(matches!(err, BundleError::LightField { .. }), "{err}");
        assert!(entries(root.path()).is_empty());
        l.extend(std::iter::repeat_n(f32::NAN, d.n_samples_per_band()));
        let err = write_bundle(&dir, &d, &l, &[], 4).unwrap_err();
        assert!(matches!(err, BundleError::LightField { .. }), "{err}");
    }

    #[test]
    fn a_manifest_listing_a_traversal_name_is_refused_before_reading() {
        // A hostile manifest must not make the reader open files outside the bundle.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        fs::write(root.path().join("outside.json"), b"{}").unwrap();
        rewrite_manifest(&dir, |m| {
            m.files.last_mut().unwrap().name = "../outside.json".to_string()
        });
        let err = read_bundle(&dir).unwrap_err();
        assert!(matches!(err, BundleError::UnsafeName { .. }), "{err}");
    }

    #[test]
    fn a_manifest_claiming_a_huge_file_is_refused_before_reading() {
        // Zip-bomb guard: the manifest's sizes are capped before any entry is read.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        rewrite_manifest(&dir, |m| m.files.last_mut().unwrap().bytes = 10 << 30);
        let err = read_bundle(&dir).unwrap_err();
        assert!(matches!(err, BundleError::TooLarge { .. }), "{err}");
    }

    #[test]
    fn a_hostile_zip_is_read_only_as_far_as_the_manifest_allows() {
        // A zip may carry unlisted traversal entries (never read) and a listed entry that inflates far
        // beyond its stated size (reading stops one byte past it).
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        let (d, l, _) = write_small(&dir);
        let build = |bomb: bool| {
            let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
            let opts = zip::write::SimpleFileOptions::default();
            w.start_file("../evil", opts).unwrap();
            w.write_all(b"evil").unwrap();
            for name in entries(&dir) {
                w.start_file(name.as_str(), opts).unwrap();
                if bomb && name == "frame_3.png" {
                    let zeros = vec![0u8; 1 << 20];
                    for _ in 0..32 {
                        w.write_all(&zeros).unwrap();
                    }
                } else {
                    w.write_all(&fs::read(dir.join(&name)).unwrap()).unwrap();
                }
            }
            w.finish().unwrap().into_inner()
        };
        let path = root.path().join("hostile.zip");
        fs::write(&path, build(false)).unwrap();
        let (_, back) = read_bundle(&path).unwrap();
        assert_close(&back, &l, (d.l_max / 65535.0) as f32);
        assert!(!root.path().join("evil").exists());
        fs::write(&path, build(true)).unwrap();
        let err = read_bundle(&path).unwrap_err();
        assert!(
            matches!(&err, BundleError::Size { name, expected, actual } if name == "frame_3.png" && *actual == expected + 1),
            "{err}"
        );
    }

    #[test]
    fn a_missing_file_is_named() {
        // The error must say which listed file is absent.
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_small(&dir);
        fs::remove_file(dir.join(MASK_FILE)).unwrap();
        let err = read_bundle(&dir).unwrap_err();
        assert!(
            matches!(&err, BundleError::Missing { name } if name == MASK_FILE),
            "{err}"
        );
    }

    #[test]
    fn file_roles_serialise_with_a_kind_tag() {
        // The documented JSON form of FileRole.
        let json = serde_json::to_string(&FileRole::Frame { band: 2 }).unwrap();
        assert_eq!(json, r#"{"kind":"frame","band":2}"#);
        assert_eq!(
            serde_json::to_string(&FileRole::BarrierMask).unwrap(),
            r#"{"kind":"barrier_mask"}"#
        );
        assert_eq!(
            serde_json::from_str::<FileRole>(r#"{"kind":"other"}"#).unwrap(),
            FileRole::Other
        );
    }
}
