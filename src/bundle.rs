//! The frame bundle: what an encode hands to the display.
//!
//! A bundle is a directory, or a `.zip` of one, holding
//! - one 16-bit greyscale PNG per projector, `frame_<n>.png`, of (X·U)×(Y·V) pixels with
//!   pixel (x·U+i, y·V+j) = round(L(x, y, i, j, n)/L_max·65535) (DESIGN §2);
//! - the barrier mask, `barrier_mask.png`, 8-bit grey, 255 = open ([`DisplayGeometry::barrier_mask`]);
//! - any extra files the caller adds (an evaluation report, say);
//! - `manifest.json` ([`Manifest`]): format version, display geometry with its projector spectra and L_max,
//!   the profile's label, the document's SHA-256, encoder and solver records, and the SHA-256 and size of
//!   every other file.
//!
//! The checksums catch corruption and accidental edits, not forgery: whoever can rewrite the files can
//! rewrite the manifest too.
//!
//! Writing is atomic: everything goes into a hidden temporary sibling directory that is renamed into place
//! only once every file is on disk, so nobody ever sees a partial bundle. Reading verifies sizes, checksums
//! and geometry before it returns a light field, and treats a zip as hostile: it reads only the plain file
//! names the manifest lists, never extracts anything to disk, and caps how much it inflates.

use std::collections::HashSet;
use std::fs;
use std::io::{Cursor, Read, Seek, Write};
use std::path::{Path, PathBuf};

use image::codecs::png::PngDecoder;
use image::{ColorType, DynamicImage, ImageDecoder, ImageFormat};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::display::DisplayGeometry;
use crate::imaging::grey16;

/// Version of the bundle layout written by [`write_bundle`]; [`read_bundle`] accepts only this one.
pub const FORMAT_VERSION: u32 = 1;

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

/// The contents of `manifest.json`: everything needed to show and to audit a bundle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Layout version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// When the bundle was written, RFC 3339 in UTC.
    pub created_at: String,
    /// The display the frames are for, including its projector spectra and L_max.
    pub display: DisplayGeometry,
    /// Width of every frame, pixels (X·U).
    pub frame_width: u32,
    /// Height of every frame, pixels (Y·V).
    pub frame_height: u32,
    /// Number of frames, one per projector band.
    pub n_frames: u32,
    /// Resolution of the barrier-mask PNG, pixels per hole pitch.
    pub barrier_mask_pixels_per_hole: u32,
    /// Identifier and version of the target's profile; never the profile's contents.
    pub profile_label: String,
    /// Lower-case hex SHA-256 of the document that was encoded.
    pub document_sha256: String,
    /// The encoder: method and its parameters.
    pub encoder: serde_json::Value,
    /// Solver statistics: iterations, termination, final objective, time, ...
    pub solver: serde_json::Value,
    /// Every file of the bundle except the manifest itself.
    pub files: Vec<FileEntry>,
}

/// One file of a bundle as listed in the manifest.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// Plain file name within the bundle (no directories).
    pub name: String,
    /// Lower-case hex SHA-256 of the file's bytes.
    pub sha256: String,
    /// Size of the file, bytes.
    pub bytes: u64,
    /// What the file is.
    pub role: FileRole,
}

/// What a bundle file is. In JSON the variant is a `kind` tag: `{"kind": "frame", "band": 0}`,
/// `{"kind": "barrier_mask"}`, `{"kind": "other"}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FileRole {
    /// The frame of one projector band.
    Frame {
        /// The band (projector) index n.
        band: u32,
    },
    /// The barrier-mask PNG.
    BarrierMask,
    /// Anything else (a report, say): checksummed, otherwise not interpreted.
    Other,
}

/// What the caller records about an encode in the manifest.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BundleMeta {
    /// Identifier and version of the target's profile; never the profile's contents.
    pub profile_label: String,
    /// Lower-case hex SHA-256 of the document (see [`sha256_hex`]).
    pub document_sha256: String,
    /// The encoder: method and its parameters (the serialised `EncodeOptions`).
    pub encoder: serde_json::Value,
    /// Solver statistics: iterations, termination, final objective, time, ...
    pub solver: serde_json::Value,
}

/// Why a bundle could not be written, read or zipped. Every message names the file and the problem.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BundleError {
    /// A file system operation failed.
    #[error("cannot {op} {}", path.display())]
    Io {
        /// What was being done ("read", "create", "rename", ...).
        op: &'static str,
        /// The path.
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
    UnsafeName {
        /// The name.
        name: String,
    },
    /// A file name used twice, or one that clashes with a name the bundle reserves.
    #[error("{name:?} appears twice in the bundle or clashes with a file the bundle writes itself")]
    DuplicateName {
        /// The name.
        name: String,
    },
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

fn io_err<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> BundleError + 'a {
    move |source| BundleError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

fn geometry(reason: String) -> BundleError {
    BundleError::Geometry { reason }
}

/// Accepts only names that stay inside the bundle directory on every platform and are not hidden.
fn check_plain_name(name: &str) -> Result<(), BundleError> {
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
    meta: &BundleMeta,
    extra_files: &[(String, Vec<u8>)],
    mask_pixels_per_hole: u32,
) -> Result<Manifest, BundleError> {
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
    let mask_k = mask_pixels_per_hole;
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
    check_target_dir(dir)?;

    // Encode before touching the disk: a failure here leaves nothing to clean up.
    let (width, height) = display.frame_size();
    let mut contents: Vec<(String, Vec<u8>, FileRole)> = Vec::with_capacity(n_bands + 1 + extra_files.len());
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

    let manifest = Manifest {
        format_version: FORMAT_VERSION,
        created_at: chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true),
        display: display.clone(),
        frame_width: width,
        frame_height: height,
        n_frames: n_bands as u32,
        barrier_mask_pixels_per_hole: mask_k,
        profile_label: meta.profile_label.clone(),
        document_sha256: meta.document_sha256.clone(),
        encoder: meta.encoder.clone(),
        solver: meta.solver.clone(),
        files: contents
            .iter()
            .map(|(name, bytes, role)| FileEntry {
                name: name.clone(),
                sha256: sha256_hex(bytes),
                bytes: bytes.len() as u64,
                role: *role,
            })
            .collect(),
    };
    let mut manifest_json = serde_json::to_vec_pretty(&manifest).map_err(|e| BundleError::Manifest {
        reason: format!("cannot serialise: {e}"),
    })?;
    manifest_json.push(b'\n');
    contents.push((MANIFEST_FILE.to_string(), manifest_json, FileRole::Other));

    let (parent, base) = split_dir(dir)?;
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{base}.tmp-"))
        .tempdir_in(&parent)
        .map_err(io_err("create a temporary directory in", &parent))?;
    // From here on, returning early drops `tmp`, which removes it and everything in it.
    for (name, bytes, _) in &contents {
        write_synced(&tmp.path().join(name), bytes)?;
    }
    sync_dir(tmp.path())?;
    fs::rename(tmp.path(), dir).map_err(|source| match source.kind() {
        // Someone filled `dir` after the check above.
        std::io::ErrorKind::DirectoryNotEmpty | std::io::ErrorKind::AlreadyExists => BundleError::NotEmpty {
            path: dir.to_path_buf(),
        },
        _ => BundleError::Io {
            op: "rename the temporary bundle to",
            path: dir.to_path_buf(),
            source,
        },
    })?;
    // The directory now lives at `dir`; stop `tmp` from trying to remove its old path.
    let _ = tmp.keep();
    // Best effort: the bundle is complete and in place; failing now would report an error for a bundle
    // that exists (and a retry would then hit `NotEmpty`).
    let _ = sync_dir(&parent);
    Ok(manifest)
}

/// `dir` must be absent or an empty directory.
fn check_target_dir(dir: &Path) -> Result<(), BundleError> {
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
fn split_dir(dir: &Path) -> Result<(PathBuf, String), BundleError> {
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

fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), BundleError> {
    let mut f = fs::File::create_new(path).map_err(io_err("create", path))?;
    f.write_all(bytes).map_err(io_err("write", path))?;
    f.sync_all().map_err(io_err("sync", path))
}

/// Makes a directory's entries durable (a rename or a new file is only safe once its directory is synced).
fn sync_dir(dir: &Path) -> Result<(), BundleError> {
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

fn encode_png(name: &str, img: &DynamicImage) -> Result<Vec<u8>, BundleError> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png).map_err(|e| BundleError::Png {
        name: name.to_string(),
        reason: e.to_string(),
    })?;
    Ok(out.into_inner())
}

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

    let manifest_bytes = source.read(MANIFEST_FILE, MAX_MANIFEST_BYTES)?;
    if manifest_bytes.len() as u64 > MAX_MANIFEST_BYTES {
        return Err(BundleError::TooLarge {
            name: MANIFEST_FILE.to_string(),
            limit: MAX_MANIFEST_BYTES,
        });
    }
    let manifest: Manifest =
        serde_json::from_slice(&manifest_bytes).map_err(|e| BundleError::Manifest { reason: e.to_string() })?;
    let layout = check_manifest(&manifest)?;

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
    Ok((manifest, l))
}

/// Where each role sits in `Manifest::files`.
struct Layout {
    /// Index of band n's frame entry.
    frames: Vec<usize>,
    /// Index of the barrier-mask entry.
    mask: usize,
}

/// Checks the manifest on its own: version, names, limits, and that display, frames and mask agree.
fn check_manifest(m: &Manifest) -> Result<Layout, BundleError> {
    if m.format_version != FORMAT_VERSION {
        return Err(BundleError::Manifest {
            reason: format!(
                "format version {} is not supported (this reader knows {FORMAT_VERSION})",
                m.format_version
            ),
        });
    }
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
    let k = m.barrier_mask_pixels_per_hole;
    if !(1..=MAX_MASK_PIXELS_PER_HOLE).contains(&k)
        || d.holes_x as u64 * d.holes_y as u64 * k as u64 * k as u64 > MAX_MASK_PIXELS
    {
        return Err(geometry(format!(
            "barrier_mask_pixels_per_hole = {k} must be within 1..={MAX_MASK_PIXELS_PER_HOLE} and give at most \
             {MAX_MASK_PIXELS} pixels"
        )));
    }
    Ok(Layout { frames, mask })
}

/// Decodes a PNG after checking its header: exact size and colour type, so nothing oversized is inflated.
fn decode_png(
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
enum Source {
    Dir(PathBuf),
    Zip(Box<zip::ZipArchive<std::io::BufReader<fs::File>>>),
}

impl Source {
    /// Reads a listed file and checks its size and SHA-256 against the manifest entry.
    fn read_verified(&mut self, entry: &FileEntry) -> Result<Vec<u8>, BundleError> {
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
    fn read(&mut self, name: &str, limit: u64) -> Result<Vec<u8>, BundleError> {
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

/// Zips the bundle directory `dir` into `out` for download: `manifest.json` first, then the files it lists
/// in the manifest's order, nothing else. Each file's size and SHA-256 are checked on the way, so a damaged
/// bundle is not shipped. The archive is reproducible: fixed timestamps (1980-01-01) and permissions, PNGs
/// stored (already compressed), other files deflated.
pub fn zip_bundle<W: Write + Seek>(dir: &Path, out: W) -> Result<(), BundleError> {
    let mut source = Source::Dir(dir.to_path_buf());
    let manifest_bytes = source.read(MANIFEST_FILE, MAX_MANIFEST_BYTES)?;
    if manifest_bytes.len() as u64 > MAX_MANIFEST_BYTES {
        return Err(BundleError::TooLarge {
            name: MANIFEST_FILE.to_string(),
            limit: MAX_MANIFEST_BYTES,
        });
    }
    let manifest: Manifest =
        serde_json::from_slice(&manifest_bytes).map_err(|e| BundleError::Manifest { reason: e.to_string() })?;
    check_manifest(&manifest)?;

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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn small_display() -> DisplayGeometry {
        DisplayGeometry {
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

    fn meta() -> BundleMeta {
        BundleMeta {
            profile_label: "alice@3".to_string(),
            document_sha256: sha256_hex(b"document"),
            encoder: serde_json::json!({ "method": "multiplex" }),
            solver: serde_json::json!({ "iterations": 12 }),
        }
    }

    fn write_small(dir: &Path) -> (DisplayGeometry, Vec<f32>, Manifest) {
        let d = small_display();
        let l = random_field(&d, 7);
        let extra = vec![("report.json".to_string(), b"{}".to_vec())];
        let m = write_bundle(dir, &d, &l, &meta(), &extra, 4).unwrap();
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
        // DESIGN §2: pixel (x·U+i, y·V+j) of frame n is L(x, y, i, j, n)/L_max.
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
        let err = write_bundle(&dir, &d, &random_field(&d, 1), &meta(), &[], 4).unwrap_err();
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
        let err = write_bundle(&dir, &d, &l, &meta(), &traversal, 4).unwrap_err();
        assert!(matches!(err, BundleError::UnsafeName { .. }), "{err}");
        assert!(entries(root.path()).is_empty());
        let too_long = vec![("r".repeat(300), b"x".to_vec())];
        let err = write_bundle(&dir, &d, &l, &meta(), &too_long, 4).unwrap_err();
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
        let err = write_bundle(&dir, &d, &l, &meta(), &[], 4).unwrap_err();
        assert!(matches!(err, BundleError::LightField { .. }), "{err}");
        assert!(entries(root.path()).is_empty());
        l.extend(std::iter::repeat_n(f32::NAN, d.n_samples_per_band()));
        let err = write_bundle(&dir, &d, &l, &meta(), &[], 4).unwrap_err();
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
