//! Writing a bundle atomically.

use crate::bundle::{
    check_plain_name, check_target_dir, frame_file_name, geometry, sha256_hex, write_dir_atomically, BundleError,
    FileEntry, FileRole, Manifest, FORMAT_VERSION, MANIFEST_FILE, MASK_FILE, MAX_BUNDLE_BYTES, MAX_FILE_BYTES,
    MAX_MASK_PIXELS, MAX_MASK_PIXELS_PER_HOLE,
};
use crate::imaging::grey16;
use crate::physics::display::DisplayGeometry;
use image::{DynamicImage, ImageFormat};
use std::collections::HashSet;
use std::io::Cursor;
use std::path::Path;

/// Writes a bundle for light field `l` (band-interleaved: `l[p * n_bands + n]` for sample p in
/// [`DisplayGeometry::sample_index`] order and band n, values in [0, L_max]) into the directory `dir`.
///
/// Files: one 16-bit greyscale PNG per projector (value = round(L/L_max·65535); values outside [0, L_max]
/// are clamped, non-finite ones rejected), the barrier mask as an 8-bit grey PNG at `mask_pixels_per_hole`
/// pixels per hole pitch, each of `extra_files` (listed with role [`FileRole::Other`]; names must be plain
/// file names: no '/', '\\', ':', '..' or leading '.'), and `manifest.json`.
///
/// Atomic: everything is written and fsynced into a fresh hidden sibling directory (`.<name>.tmp-<random>`
/// next to `dir`), which is then renamed to `dir`. `dir` must not exist yet or be an empty directory, and
/// its parent must exist. On any error the temporary directory is removed, so no partial bundle is ever
/// left behind. On Unix the bundle directory ends up readable by its owner only (mode 0700), since the
/// frames carry the document.
///
/// Returns the manifest as written.
pub fn write_bundle(
    dir: &Path,
    display: &DisplayGeometry,
    l: &[f32],
    extra_files: &[(String, Vec<u8>)],
    mask_pixels_per_hole: u32,
) -> Result<Manifest, BundleError> {
    check_target_dir(dir)?;
    // Encode before touching the disk: a failure here leaves nothing to clean up.
    let (manifest, files) = encode_bundle(display, l, extra_files, mask_pixels_per_hole)?;
    let contents: Vec<(String, Vec<u8>, ())> = files.into_iter().map(|(name, bytes)| (name, bytes, ())).collect();
    write_dir_atomically(dir, &contents)?;
    Ok(manifest)
}

/// The files of a bundle, encoded in memory and checked exactly as [`write_bundle`] checks them: the frames,
/// the barrier mask, `extra_files` and last `manifest.json`, as (name, bytes). For callers that store the
/// bundle elsewhere than in a plain directory (the service seals every file before it touches the disk).
pub fn encode_bundle(
    display: &DisplayGeometry,
    l: &[f32],
    extra_files: &[(String, Vec<u8>)],
    mask_pixels_per_hole: u32,
) -> Result<(Manifest, Vec<NamedBytes>), BundleError> {
    check_inputs(display, l, extra_files, mask_pixels_per_hole)?;
    let contents = encode_files(display, l, extra_files, mask_pixels_per_hole)?;
    let manifest = manifest_for(display, &contents, mask_pixels_per_hole);
    let mut manifest_json = serde_json::to_vec_pretty(&manifest).map_err(|e| BundleError::Manifest {
        reason: format!("cannot serialise: {e}"),
    })?;
    manifest_json.push(b'\n');
    let mut files: Vec<(String, Vec<u8>)> = contents.into_iter().map(|(name, bytes, _)| (name, bytes)).collect();
    files.push((MANIFEST_FILE.to_string(), manifest_json));
    Ok((manifest, files))
}

/// A file's name and contents.
pub type NamedBytes = (String, Vec<u8>);

/// A bundle file before it is written: name, bytes, role.
type Content = (String, Vec<u8>, FileRole);

/// Checks the light field's size and values, the mask resolution and the extra files' names and sizes.
fn check_inputs(
    display: &DisplayGeometry,
    l: &[f32],
    extra_files: &[(String, Vec<u8>)],
    mask_k: u32,
) -> Result<(), BundleError> {
    display.validate().map_err(|e| geometry(format!("display: {e}")))?;
    let n_bands = display.n_bands();
    let n_samples = display.n_samples_per_band();
    if l.len() != n_samples * n_bands {
        return Err(BundleError::LightField {
            reason: format!(
                "{} values given, the display needs {} ({} samples × {} bands)",
                l.len(),
                n_samples * n_bands,
                n_samples,
                n_bands
            ),
        });
    }
    if let Some(k) = l.iter().position(|v| !v.is_finite()) {
        return Err(BundleError::LightField {
            reason: format!("sample {} of band {} is {}", k / n_bands, k % n_bands, l[k]),
        });
    }
    let mask_pixels = display.holes_x as u64 * display.holes_y as u64 * mask_k as u64 * mask_k as u64;
    if !(1..=MAX_MASK_PIXELS_PER_HOLE).contains(&mask_k) || mask_pixels > MAX_MASK_PIXELS {
        return Err(geometry(format!(
            "{MASK_FILE}: {mask_k} pixels per hole must be within 1..={MAX_MASK_PIXELS_PER_HOLE} \
             and give at most {MAX_MASK_PIXELS} pixels (got {mask_pixels})"
        )));
    }
    let mut names: HashSet<String> = (0..n_bands).map(frame_file_name).collect();
    names.insert(MASK_FILE.to_string());
    names.insert(MANIFEST_FILE.to_string());
    for (name, bytes) in extra_files {
        check_plain_name(name)?;
        if !names.insert(name.clone()) {
            return Err(BundleError::DuplicateName { name: name.clone() });
        }
        if bytes.len() as u64 > MAX_FILE_BYTES {
            return Err(BundleError::TooLarge {
                name: name.clone(),
                limit: MAX_FILE_BYTES,
            });
        }
    }
    Ok(())
}

/// The frames (one 16-bit PNG per band, pixel = L/L_max), the barrier mask and the extra files, encoded.
fn encode_files(
    display: &DisplayGeometry,
    l: &[f32],
    extra_files: &[(String, Vec<u8>)],
    mask_k: u32,
) -> Result<Vec<Content>, BundleError> {
    let (n_bands, n_samples) = (display.n_bands(), display.n_samples_per_band());
    let (width, height) = display.frame_size();
    let mut contents: Vec<Content> = Vec::with_capacity(n_bands + 2 + extra_files.len());
    let scale = 1.0 / display.l_max;
    let mut frame = vec![0f32; n_samples];
    for band in 0..n_bands {
        for (p, v) in frame.iter_mut().enumerate() {
            *v = (l[p * n_bands + band] as f64 * scale) as f32;
        }
        let name = frame_file_name(band);
        let png = encode_png(&name, &DynamicImage::ImageLuma16(grey16(&frame, width, height)))?;
        contents.push((name, png, FileRole::Frame { band: band as u32 }));
    }
    drop(frame);
    let (mask_w, mask_h, mask) = display.barrier_mask(mask_k);
    let mask = image::GrayImage::from_raw(mask_w, mask_h, mask)
        .ok_or_else(|| geometry(format!("{MASK_FILE}: mask buffer does not match {mask_w}×{mask_h}")))?;
    contents.push((
        MASK_FILE.to_string(),
        encode_png(MASK_FILE, &DynamicImage::ImageLuma8(mask))?,
        FileRole::BarrierMask,
    ));
    for (name, bytes) in extra_files {
        contents.push((name.clone(), bytes.clone(), FileRole::Other));
    }
    let total: u64 = contents.iter().map(|(_, b, _)| b.len() as u64).sum();
    if total > MAX_BUNDLE_BYTES {
        return Err(BundleError::TooLarge {
            name: "bundle".to_string(),
            limit: MAX_BUNDLE_BYTES,
        });
    }
    Ok(contents)
}

/// The manifest listing `contents` with their checksums.
fn manifest_for(display: &DisplayGeometry, contents: &[Content], mask_k: u32) -> Manifest {
    let (width, height) = display.frame_size();
    Manifest {
        format_version: FORMAT_VERSION,
        display: display.clone(),
        frame_width: width,
        frame_height: height,
        n_frames: display.n_bands() as u32,
        barrier_mask_pixels_per_hole: mask_k,
        files: contents
            .iter()
            .map(|(name, bytes, role)| FileEntry {
                name: name.clone(),
                sha256: sha256_hex(bytes),
                bytes: bytes.len() as u64,
                role: *role,
            })
            .collect(),
    }
}

pub(crate) fn encode_png(name: &str, img: &DynamicImage) -> Result<Vec<u8>, BundleError> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png).map_err(|e| BundleError::Png {
        name: name.to_string(),
        reason: e.to_string(),
    })?;
    Ok(out.into_inner())
}
