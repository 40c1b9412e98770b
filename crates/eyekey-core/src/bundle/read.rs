//! Reading and verifying a bundle from a directory or a zip.

use crate::bundle::{
    check_plain_name, geometry, io_err, sha256_hex, BundleError, FileEntry, FileRole, Manifest, FORMAT_VERSION,
    MANIFEST_FILE, MASK_FILE, MAX_BUNDLE_BYTES, MAX_FILE_BYTES, MAX_MANIFEST_BYTES, MAX_MASK_PIXELS,
    MAX_MASK_PIXELS_PER_HOLE,
};
use image::codecs::png::PngDecoder;
use image::{ColorType, DynamicImage, ImageDecoder};
use std::collections::HashSet;
use std::fs;
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

/// Reads the bundle at `path`, a directory or a `.zip` of one (the files at the archive's top level).
///
/// Parses `manifest.json`; checks that every listed name is plain and listed once; verifies every listed
/// file's size and SHA-256; checks that the display validates, that its frame size is
/// `frame_width`×`frame_height`, that `n_frames` equals the number of projector bands and there is exactly
/// one frame entry per band, that each frame is a 16-bit greyscale PNG of that size, and that the barrier
/// mask is an 8-bit grey PNG of `barrier_mask_pixels_per_hole` pixels per hole. Sizes are capped
/// ([`MAX_MANIFEST_BYTES`], [`MAX_FILE_BYTES`], [`MAX_BUNDLE_BYTES`]); entries of a zip that the manifest
/// does not list are never read.
///
/// Returns the manifest and the light field, band-interleaved like [`write_bundle`]'s input, with
/// L = v/65535·L_max.
pub fn read_bundle(path: &Path) -> Result<(Manifest, Vec<f32>), BundleError> {
    let b = read_verified_bundle(path)?;
    Ok((b.manifest, b.light_field))
}

/// A bundle read and verified by [`read_verified_bundle`].
#[derive(Clone, Debug)]
pub struct VerifiedBundle {
    /// The parsed manifest.
    pub manifest: Manifest,
    /// `manifest.json` exactly as read.
    pub manifest_bytes: Vec<u8>,
    /// The light field, as [`read_bundle`] returns it.
    pub light_field: Vec<f32>,
    /// Every listed file's verified bytes, in the manifest's order, as (name, bytes).
    pub files: Vec<(String, Vec<u8>)>,
}

/// Reads and verifies the bundle at `path` like [`read_bundle`], and also returns the verified bytes of every
/// file, so a caller that installs the bundle need not read (or inflate) it a second time.
pub fn read_verified_bundle(path: &Path) -> Result<VerifiedBundle, BundleError> {
    let meta = fs::metadata(path).map_err(io_err("open", path))?;
    let mut source = if meta.is_dir() {
        Source::Dir(path.to_path_buf())
    } else {
        let file = fs::File::open(path).map_err(io_err("open", path))?;
        let archive = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| BundleError::Zip {
            reason: format!("{}: {e}", path.display()),
        })?;
        Source::Zip(Box::new(archive))
    };

    let (manifest_bytes, manifest, layout) = read_manifest(&mut source)?;

    // Every listed file, verified before anything is decoded.
    let mut contents = Vec::with_capacity(manifest.files.len());
    for entry in &manifest.files {
        let bytes = source.read_verified(entry)?;
        contents.push(bytes);
    }

    let display = &manifest.display;
    let n_bands = display.n_bands();
    let (width, height) = (manifest.frame_width, manifest.frame_height);
    let l_max = display.l_max;
    let mut l = vec![0f32; display.n_samples_per_band() * n_bands];
    for (band, &file) in layout.frames.iter().enumerate() {
        let name = &manifest.files[file].name;
        let img = decode_png(
            name,
            &contents[file],
            (width, height),
            ColorType::L16,
            "16-bit greyscale",
        )?;
        let DynamicImage::ImageLuma16(img) = img else {
            return Err(geometry(format!("{name}: not 16-bit greyscale")));
        };
        for (p, &v) in img.as_raw().iter().enumerate() {
            l[p * n_bands + band] = (v as f64 / 65535.0 * l_max) as f32;
        }
    }
    let k = manifest.barrier_mask_pixels_per_hole;
    let mask_size = (display.holes_x * k, display.holes_y * k);
    decode_png(
        MASK_FILE,
        &contents[layout.mask],
        mask_size,
        ColorType::L8,
        "8-bit greyscale",
    )?;
    let files = manifest.files.iter().map(|e| e.name.clone()).zip(contents).collect();
    Ok(VerifiedBundle {
        manifest,
        manifest_bytes,
        light_field: l,
        files,
    })
}

/// Reads `manifest.json` from `source` (capped at [`MAX_MANIFEST_BYTES`]), parses and checks it; returns its
/// bytes, the manifest and where each role sits in its file list.
pub(crate) fn read_manifest(source: &mut Source) -> Result<(Vec<u8>, Manifest, Layout), BundleError> {
    let manifest_bytes = source.read(MANIFEST_FILE, MAX_MANIFEST_BYTES)?;
    if manifest_bytes.len() as u64 > MAX_MANIFEST_BYTES {
        return Err(BundleError::TooLarge {
            name: MANIFEST_FILE.to_string(),
            limit: MAX_MANIFEST_BYTES,
        });
    }
    // The version first, so that a bundle of another layout is refused as such, not for a field it names.
    #[derive(serde::Deserialize)]
    struct Version {
        format_version: u32,
    }
    let bad = |e: serde_json::Error| BundleError::Manifest { reason: e.to_string() };
    let version: Version = serde_json::from_slice(&manifest_bytes).map_err(bad)?;
    check_version(version.format_version)?;
    let manifest: Manifest = if version.format_version == 1 {
        // The first layout also recorded the encoder, the solver, the profile's label and a time; a display never
        // needed them, and bundles made before they left are still shown.
        let mut value: serde_json::Value = serde_json::from_slice(&manifest_bytes).map_err(bad)?;
        if let Some(fields) = value.as_object_mut() {
            for legacy in ["created_at", "profile_label", "encoder", "solver"] {
                fields.remove(legacy);
            }
        }
        serde_json::from_value(value).map_err(bad)?
    } else {
        serde_json::from_slice(&manifest_bytes).map_err(bad)?
    };
    let layout = check_manifest(&manifest)?;
    Ok((manifest_bytes, manifest, layout))
}

/// Where each role sits in `Manifest::files`.
pub(crate) struct Layout {
    /// Index of band n's frame entry.
    frames: Vec<usize>,
    /// Index of the barrier-mask entry.
    mask: usize,
}

/// Refuses a layout version other than [`FORMAT_VERSION`] and 1 (read with its encoder record ignored).
fn check_version(version: u32) -> Result<(), BundleError> {
    if version == FORMAT_VERSION || version == 1 {
        return Ok(());
    }
    Err(BundleError::Manifest {
        reason: format!("format version {version} is not supported (this reader knows 1 and {FORMAT_VERSION})"),
    })
}

/// Checks the manifest on its own: version, names, limits, and that display, frames and mask agree.
pub(crate) fn check_manifest(m: &Manifest) -> Result<Layout, BundleError> {
    check_version(m.format_version)?;
    check_files(m)?;
    check_geometry(m)?;
    let layout = roles_of(m)?;
    let d = &m.display;
    let k = m.barrier_mask_pixels_per_hole;
    if !(1..=MAX_MASK_PIXELS_PER_HOLE).contains(&k)
        || d.holes_x as u64 * d.holes_y as u64 * k as u64 * k as u64 > MAX_MASK_PIXELS
    {
        return Err(geometry(format!(
            "barrier_mask_pixels_per_hole = {k} must be within 1..={MAX_MASK_PIXELS_PER_HOLE} and give at most \
             {MAX_MASK_PIXELS} pixels"
        )));
    }
    Ok(layout)
}

/// Every listed name is plain and listed once; sizes stay within the limits.
fn check_files(m: &Manifest) -> Result<(), BundleError> {
    let mut names = HashSet::new();
    names.insert(MANIFEST_FILE);
    let mut total = 0u64;
    for entry in &m.files {
        check_plain_name(&entry.name)?;
        if !names.insert(entry.name.as_str()) {
            return Err(BundleError::DuplicateName {
                name: entry.name.clone(),
            });
        }
        if entry.bytes > MAX_FILE_BYTES {
            return Err(BundleError::TooLarge {
                name: entry.name.clone(),
                limit: MAX_FILE_BYTES,
            });
        }
        total += entry.bytes;
    }
    if total > MAX_BUNDLE_BYTES {
        return Err(BundleError::TooLarge {
            name: "bundle".to_string(),
            limit: MAX_BUNDLE_BYTES,
        });
    }

    Ok(())
}

/// The display validates and agrees with the frame size and count.
fn check_geometry(m: &Manifest) -> Result<(), BundleError> {
    let d = &m.display;
    d.validate()
        .map_err(|e| geometry(format!("{MANIFEST_FILE}: display: {e}")))?;
    let (w, h) = d.frame_size();
    if (w, h) != (m.frame_width, m.frame_height) {
        return Err(geometry(format!(
            "the display's {}×{} holes of {}×{} views make {w}×{h} frames, the manifest says {}×{}",
            d.holes_x, d.holes_y, d.views_u, d.views_v, m.frame_width, m.frame_height
        )));
    }
    if m.n_frames as usize != d.n_bands() {
        return Err(geometry(format!(
            "the manifest lists n_frames = {} but the display has {} projectors",
            m.n_frames,
            d.n_bands()
        )));
    }
    Ok(())
}

/// Where each frame and the mask sit in the file list: exactly one frame per band and one mask.
fn roles_of(m: &Manifest) -> Result<Layout, BundleError> {
    let d = &m.display;
    let mut frames = vec![None; d.n_bands()];
    let mut mask = None;
    for (i, entry) in m.files.iter().enumerate() {
        match entry.role {
            FileRole::Frame { band } => {
                let slot = frames.get_mut(band as usize).ok_or_else(|| {
                    geometry(format!(
                        "{}: band {band} but the display has {} projectors",
                        entry.name,
                        d.n_bands()
                    ))
                })?;
                if slot.replace(i).is_some() {
                    return Err(geometry(format!("{}: a second frame for band {band}", entry.name)));
                }
            }
            FileRole::BarrierMask => {
                if mask.replace(i).is_some() {
                    return Err(BundleError::Manifest {
                        reason: format!("{}: a second barrier mask", entry.name),
                    });
                }
            }
            FileRole::Other => {}
        }
    }
    let frames = frames
        .into_iter()
        .enumerate()
        .map(|(band, f)| f.ok_or_else(|| geometry(format!("no frame is listed for band {band} of {}", d.n_bands()))))
        .collect::<Result<Vec<_>, _>>()?;
    let mask = mask.ok_or_else(|| BundleError::Manifest {
        reason: "no barrier mask is listed".to_string(),
    })?;
    Ok(Layout { frames, mask })
}

/// Decodes a PNG after checking its header: exact size and colour type, so nothing oversized is inflated.
pub(crate) fn decode_png(
    name: &str,
    bytes: &[u8],
    size: (u32, u32),
    color: ColorType,
    color_name: &str,
) -> Result<DynamicImage, BundleError> {
    let png_err = |e: image::ImageError| BundleError::Png {
        name: name.to_string(),
        reason: e.to_string(),
    };
    let decoder = PngDecoder::new(Cursor::new(bytes)).map_err(png_err)?;
    let (w, h) = decoder.dimensions();
    if (w, h) != size {
        return Err(geometry(format!(
            "{name} is {w}×{h} pixels, the manifest's geometry needs {}×{}",
            size.0, size.1
        )));
    }
    if decoder.color_type() != color {
        return Err(geometry(format!(
            "{name} is {:?}, expected {color_name}",
            decoder.color_type()
        )));
    }
    DynamicImage::from_decoder(decoder).map_err(png_err)
}

/// Where a bundle's files come from.
pub(crate) enum Source {
    Dir(PathBuf),
    Zip(Box<zip::ZipArchive<std::io::BufReader<fs::File>>>),
}

impl Source {
    /// Reads a listed file and checks its size and SHA-256 against the manifest entry.
    pub(crate) fn read_verified(&mut self, entry: &FileEntry) -> Result<Vec<u8>, BundleError> {
        let bytes = self.read(&entry.name, entry.bytes)?;
        if bytes.len() as u64 != entry.bytes {
            return Err(BundleError::Size {
                name: entry.name.clone(),
                expected: entry.bytes,
                actual: bytes.len() as u64,
            });
        }
        let actual = sha256_hex(&bytes);
        if !actual.eq_ignore_ascii_case(&entry.sha256) {
            return Err(BundleError::Checksum {
                name: entry.name.clone(),
                expected: entry.sha256.clone(),
                actual,
            });
        }
        Ok(bytes)
    }

    /// Reads the plain-named file `name`, at most `limit + 1` bytes (one past, so that an oversized file
    /// shows as a size mismatch instead of being inflated in full).
    pub(crate) fn read(&mut self, name: &str, limit: u64) -> Result<Vec<u8>, BundleError> {
        check_plain_name(name)?;
        let mut buf = Vec::new();
        match self {
            Source::Dir(dir) => {
                let path = dir.join(name);
                let file = match fs::File::open(&path) {
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                        return Err(BundleError::Missing { name: name.to_string() })
                    }
                    r => r.map_err(io_err("open", &path))?,
                };
                file.take(limit + 1)
                    .read_to_end(&mut buf)
                    .map_err(io_err("read", &path))?;
            }
            Source::Zip(archive) => {
                let entry = match archive.by_name(name) {
                    Err(zip::result::ZipError::FileNotFound) => {
                        return Err(BundleError::Missing { name: name.to_string() })
                    }
                    r => r.map_err(|e| BundleError::Zip {
                        reason: format!("{name}: {e}"),
                    })?,
                };
                entry
                    .take(limit + 1)
                    .read_to_end(&mut buf)
                    .map_err(|e| BundleError::Zip {
                        reason: format!("{name}: {e}"),
                    })?;
            }
        }
        Ok(buf)
    }
}
