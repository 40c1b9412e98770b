//! Images in and out: documents (sRGB PNG/JPEG) to objective LMS images, simulated LMS views back to sRGB.
//!
//! Conventions (docs/design.md §2 "Images"): a document is sRGB. The objective for an observer is the LMS image a
//! standard observer would see of it on an ordinary display, von-Kries adapted to the observer's own display
//! white (all projectors at L_max) and scaled by a level ≤ 1 that leaves the encoder headroom. A simulated
//! view is adapted back from the viewer's display white to sRGB white through the standard observer, so the
//! display's white at full power shows as sRGB white. Approximations: sRGB primaries through CIE 2012 XYZ,
//! von Kries adaptation, no flare or stray light.

pub mod glyphs;

use std::io::Cursor;
use std::path::Path;

use image::{ImageBuffer, Luma, Rgb, RgbImage};

use crate::physics::spectral::{
    linear_srgb_to_lms, linear_to_srgb, lms_to_linear_srgb, srgb_to_linear, srgb_white_lms,
};

/// Largest document accepted by default: 64 megapixels decoded, 64 MiB encoded.
pub const DEFAULT_MAX_PIXELS: u64 = 64_000_000;

/// Errors reading or writing images.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImagingError {
    /// The file could not be read.
    #[error("cannot read {path}")]
    Io {
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Not a PNG or JPEG, or a corrupt or truncated one.
    #[error("{what}: not a readable PNG or JPEG image ({reason})")]
    Decode {
        /// What was being read.
        what: String,
        /// Decoder message.
        reason: String,
    },
    /// The image is larger than allowed.
    #[error("{what}: {width}×{height} pixels exceeds the limit of {max_pixels} pixels")]
    TooLarge {
        /// What was being read.
        what: String,
        /// Width in the header.
        width: u32,
        /// Height in the header.
        height: u32,
        /// The limit.
        max_pixels: u64,
    },
    /// Writing failed.
    #[error("cannot write {path}: {reason}")]
    Write {
        path: String,
        /// The cause.
        reason: String,
    },
}

/// Decodes a PNG or JPEG held in memory, refusing anything whose header declares more than `max_pixels`
/// (checked before decoding, so decompression bombs never allocate).
pub fn decode_image(bytes: &[u8], what: &str, max_pixels: u64) -> Result<RgbImage, ImagingError> {
    let dec = |e: image::ImageError| ImagingError::Decode {
        what: what.to_string(),
        reason: e.to_string(),
    };
    let reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| ImagingError::Decode {
            what: what.to_string(),
            reason: e.to_string(),
        })?;
    match reader.format() {
        Some(image::ImageFormat::Png) | Some(image::ImageFormat::Jpeg) => {}
        _ => {
            return Err(ImagingError::Decode {
                what: what.to_string(),
                reason: "unrecognised format; PNG or JPEG expected".into(),
            })
        }
    }
    let (width, height) = reader.into_dimensions().map_err(dec)?;
    if width == 0 || height == 0 || width as u64 * height as u64 > max_pixels {
        return Err(ImagingError::TooLarge {
            what: what.to_string(),
            width,
            height,
            max_pixels,
        });
    }
    let mut reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| ImagingError::Decode {
            what: what.to_string(),
            reason: e.to_string(),
        })?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    limits.max_alloc = Some(max_pixels.saturating_mul(8).max(1 << 20));
    reader.limits(limits);
    Ok(reader.decode().map_err(dec)?.to_rgb8())
}

/// Reads a PNG or JPEG document from a file.
pub fn load_image(path: &Path) -> Result<RgbImage, ImagingError> {
    let bytes = std::fs::read(path).map_err(|source| ImagingError::Io {
        path: path.display().to_string(),
        source,
    })?;
    decode_image(&bytes, &path.display().to_string(), DEFAULT_MAX_PIXELS)
}

/// Writes an 8-bit sRGB PNG.
pub fn save_rgb_png(img: &RgbImage, path: &Path) -> Result<(), ImagingError> {
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| ImagingError::Write {
            path: path.display().to_string(),
            reason: e.to_string(),
        })
}

/// Resamples an image to `width`×`height` (area-averaging filter, in sRGB values).
pub fn resize(img: &RgbImage, width: u32, height: u32) -> RgbImage {
    if img.dimensions() == (width, height) {
        return img.clone();
    }
    image::imageops::resize(img, width, height, image::imageops::FilterType::Triangle)
}

/// Linear-light RGB of every pixel, row-major.
pub fn linear_rgb(img: &RgbImage) -> Vec<[f64; 3]> {
    img.pixels()
        .map(|p| {
            [
                srgb_to_linear(p[0] as f64 / 255.0),
                srgb_to_linear(p[1] as f64 / 255.0),
                srgb_to_linear(p[2] as f64 / 255.0),
            ]
        })
        .collect()
}

/// The objective LMS image (`out[r·3 + a]`) of a linear-RGB image for an observer whose display white is
/// `viewer_white` (Σ_n c_na at L_max): S' = level · W_viewer ⊙ LMS_std(rgb) / W_std.
pub fn objective_lms(rgb_linear: &[[f64; 3]], viewer_white: [f64; 3], level: f64) -> Vec<f32> {
    let w_std = srgb_white_lms();
    let mut out = Vec::with_capacity(rgb_linear.len() * 3);
    for rgb in rgb_linear {
        let lms = linear_srgb_to_lms(*rgb);
        for a in 0..3 {
            out.push((level * viewer_white[a] * lms[a] / w_std[a]) as f32);
        }
    }
    out
}

/// The sRGB picture of what a viewer with display white `viewer_white` perceives of the LMS image `lms`.
pub fn lms_to_srgb_image(lms: &[f32], width: u32, height: u32, viewer_white: [f64; 3]) -> RgbImage {
    let w_std = srgb_white_lms();
    ImageBuffer::from_fn(width, height, |x, y| {
        let r = (y * width + x) as usize;
        let adapted = [
            lms[r * 3] as f64 * w_std[0] / viewer_white[0],
            lms[r * 3 + 1] as f64 * w_std[1] / viewer_white[1],
            lms[r * 3 + 2] as f64 * w_std[2] / viewer_white[2],
        ];
        let rgb = lms_to_linear_srgb(adapted);
        let enc = |v: f64| (linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0).round() as u8;
        Rgb([enc(rgb[0]), enc(rgb[1]), enc(rgb[2])])
    })
}

/// Per-pixel projector intensities in [0, 1] that reproduce linear-RGB colours on a plain multiband display
/// for the standard observer: I = g·1 + C⁺(S − g·Cᵀ1), where g is the grey level that matches the colour's
/// mean adapted response and C⁺ the pseudo-inverse of the 3×N coupling; greys map exactly to g·1.
pub fn plain_intensities(rgb_linear: &[[f64; 3]], coupling: &[[f64; 3]]) -> Vec<f32> {
    let n = coupling.len();
    let white: [f64; 3] = std::array::from_fn(|a| coupling.iter().map(|c| c[a]).sum());
    let w_std = srgb_white_lms();
    // Pseudo-inverse of M = Cᵀ (3×N): M⁺ = Mᵀ (M Mᵀ)⁻¹ (M has full row rank for ≥ 3 distinct bands).
    let mut mmt = [[0.0f64; 3]; 3];
    for c in coupling {
        for a in 0..3 {
            for b in 0..3 {
                mmt[a][b] += c[a] * c[b];
            }
        }
    }
    let inv = invert3(mmt);
    let mut out = Vec::with_capacity(rgb_linear.len() * n);
    for rgb in rgb_linear {
        let lms = linear_srgb_to_lms(*rgb);
        let target: [f64; 3] = std::array::from_fn(|a| white[a] * lms[a] / w_std[a]);
        let g = (0..3).map(|a| target[a] / white[a]).sum::<f64>() / 3.0;
        let resid: [f64; 3] = std::array::from_fn(|a| target[a] - g * white[a]);
        let z: Option<[f64; 3]> = inv.map(|m| std::array::from_fn(|a| (0..3).map(|b| m[a][b] * resid[b]).sum()));
        for c in coupling {
            let corr = z.map_or(0.0, |z| c[0] * z[0] + c[1] * z[1] + c[2] * z[2]);
            out.push((g + corr).clamp(0.0, 1.0) as f32);
        }
    }
    out
}

/// Inverse of a 3×3 matrix, None when singular.
pub fn invert3(m: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det.abs() < 1e-300 || !det.is_finite() {
        return None;
    }
    let c = |r0: usize, c0: usize, r1: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    Some([
        [c(1, 1, 2, 2) / det, -c(0, 1, 2, 2) / det, c(0, 1, 1, 2) / det],
        [-c(1, 0, 2, 2) / det, c(0, 0, 2, 2) / det, -c(0, 0, 1, 2) / det],
        [c(1, 0, 2, 1) / det, -c(0, 0, 2, 1) / det, c(0, 0, 1, 1) / det],
    ])
}

/// A 16-bit greyscale image of `values` in [0, 1] (row-major), as projector frames are stored.
pub fn grey16(values: &[f32], width: u32, height: u32) -> ImageBuffer<Luma<u16>, Vec<u16>> {
    let data = values
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    ImageBuffer::from_raw(width, height, data).expect("buffer length matches the frame size")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn greys_map_to_equal_projector_intensities() {
        let c = [[0.2, 0.1, 0.6], [0.5, 0.6, 0.05], [0.8, 0.5, 0.0], [0.6, 0.2, 0.0]];
        let rgb = [[0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]];
        let i = plain_intensities(&rgb, &c);
        for (k, want) in [0.5f32, 0.0, 1.0].iter().enumerate() {
            for n in 0..4 {
                assert!((i[k * 4 + n] - want).abs() < 1e-4, "{:?}", &i[k * 4..k * 4 + 4]);
            }
        }
    }

    #[test]
    fn objective_and_view_round_trip_for_the_same_observer() {
        let rgb = [[0.2, 0.4, 0.6], [0.9, 0.1, 0.3]];
        let white = [1.7, 1.3, 0.9];
        let lms = objective_lms(&rgb, white, 1.0);
        let img = lms_to_srgb_image(&lms, 2, 1, white);
        for (k, p) in img.pixels().enumerate() {
            for a in 0..3 {
                let back = srgb_to_linear(p[a] as f64 / 255.0);
                assert!((back - rgb[k][a]).abs() < 0.01, "{k} {a}: {back}");
            }
        }
    }

    #[test]
    fn invert3_inverts() {
        let m = [[2.0, 1.0, 0.0], [0.5, 3.0, 1.0], [0.0, 1.0, 4.0]];
        let inv = invert3(m).unwrap();
        for (i, row) in m.iter().enumerate() {
            for j in 0..3 {
                let s: f64 = row.iter().zip(&inv).map(|(a, inv_row)| a * inv_row[j]).sum();
                assert!((s - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn garbage_and_bombs_are_refused_before_decoding() {
        assert!(matches!(
            decode_image(b"hello", "doc", 100),
            Err(ImagingError::Decode { .. })
        ));
        // A valid PNG header that declares 100000×100000 pixels.
        let mut png = Vec::new();
        png.extend_from_slice(&[0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A]);
        png.extend_from_slice(&13u32.to_be_bytes());
        png.extend_from_slice(b"IHDR");
        png.extend_from_slice(&100_000u32.to_be_bytes());
        png.extend_from_slice(&100_000u32.to_be_bytes());
        png.extend_from_slice(&[8, 2, 0, 0, 0]);
        png.extend_from_slice(&[0, 0, 0, 0]);
        let e = decode_image(&png, "doc", DEFAULT_MAX_PIXELS);
        assert!(
            matches!(e, Err(ImagingError::TooLarge { .. }) | Err(ImagingError::Decode { .. })),
            "{e:?}"
        );
    }
}
