//! Checking and decoding uploaded images without trusting them.
//!
//! The header is read first (`into_dimensions`) and the pixel count checked against the limit before
//! any pixel is decoded; decoding then runs under `image::Limits` sized to that header, so a file that
//! lies about its size (a decompression bomb) cannot allocate more than the limit allows.

use std::io::Cursor;

use image::{DynamicImage, ImageFormat, ImageReader};

/// Why an upload was refused; every message names the problem.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ImageProblem {
    /// The declared content type is not PNG or JPEG.
    #[error("unsupported content type {0:?}: send the image as image/png or image/jpeg")]
    UnsupportedType(String),
    /// The bytes are not of the declared type.
    #[error("the body is not a {declared} image (its first bytes do not match)")]
    WrongType {
        /// The declared format.
        declared: &'static str,
    },
    /// The header cannot be read.
    #[error("the {format} header could not be read ({reason}); is the file truncated?")]
    BadHeader {
        /// Format name.
        format: &'static str,
        /// Decoder's reason.
        reason: String,
    },
    /// Zero width or height.
    #[error("the image is empty ({width}×{height} pixels)")]
    Empty {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// More pixels than allowed.
    #[error("the image is {width}×{height} = {pixels} pixels; the limit is {limit} pixels")]
    TooManyPixels {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Width × height.
        pixels: u64,
        /// The limit.
        limit: u64,
    },
    /// The pixel data is truncated or corrupt.
    #[error("the {format} image data could not be decoded ({reason}); is the file truncated or corrupt?")]
    BadData {
        /// Format name.
        format: &'static str,
        /// Decoder's reason.
        reason: String,
    },
}

/// An image's format and size, read from its header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageHeader {
    /// PNG or JPEG.
    pub format: ImageFormat,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl ImageHeader {
    /// The MIME type.
    pub fn content_type(&self) -> &'static str {
        if self.format == ImageFormat::Png {
            "image/png"
        } else {
            "image/jpeg"
        }
    }

    /// A file extension.
    pub fn extension(&self) -> &'static str {
        if self.format == ImageFormat::Png {
            "png"
        } else {
            "jpg"
        }
    }
}

fn format_name(format: ImageFormat) -> &'static str {
    if format == ImageFormat::Png {
        "PNG"
    } else {
        "JPEG"
    }
}

/// Parses a `Content-Type` value into PNG or JPEG.
pub fn format_of_content_type(content_type: Option<&str>) -> Result<ImageFormat, ImageProblem> {
    let raw = content_type.unwrap_or("");
    let mime = raw.split(';').next().unwrap_or("").trim().to_ascii_lowercase();
    match mime.as_str() {
        "image/png" => Ok(ImageFormat::Png),
        "image/jpeg" | "image/jpg" => Ok(ImageFormat::Jpeg),
        _ => Err(ImageProblem::UnsupportedType(raw.to_string())),
    }
}

/// Checks the bytes against the declared format and reads the header, refusing more than `max_pixels`.
pub fn inspect(bytes: &[u8], format: ImageFormat, max_pixels: u64) -> Result<ImageHeader, ImageProblem> {
    let name = format_name(format);
    if image::guess_format(bytes).ok() != Some(format) {
        return Err(ImageProblem::WrongType { declared: name });
    }
    let (width, height) = ImageReader::with_format(Cursor::new(bytes), format)
        .into_dimensions()
        .map_err(|e| ImageProblem::BadHeader {
            format: name,
            reason: e.to_string(),
        })?;
    if width == 0 || height == 0 {
        return Err(ImageProblem::Empty { width, height });
    }
    let pixels = u64::from(width) * u64::from(height);
    if pixels > max_pixels {
        return Err(ImageProblem::TooManyPixels {
            width,
            height,
            pixels,
            limit: max_pixels,
        });
    }
    Ok(ImageHeader { format, width, height })
}

/// Decodes an image whose header passed [`inspect`], allocating no more than that header allows.
pub fn decode(bytes: &[u8], header: &ImageHeader) -> Result<DynamicImage, ImageProblem> {
    let name = format_name(header.format);
    let mut reader = ImageReader::with_format(Cursor::new(bytes), header.format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(header.width);
    limits.max_image_height = Some(header.height);
    // 16-bit RGBA is the widest layout either decoder produces: 8 bytes a pixel, plus slack for its
    // working buffers.
    limits.max_alloc = Some(u64::from(header.width) * u64::from(header.height) * 8 + (64 << 20));
    reader.limits(limits);
    reader.decode().map_err(|e| ImageProblem::BadData {
        format: name,
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(w: u32, h: u32) -> Vec<u8> {
        let img = image::RgbImage::from_pixel(w, h, image::Rgb([200, 10, 10]));
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), ImageFormat::Png).unwrap();
        out
    }

    #[test]
    fn a_small_png_passes_and_decodes() {
        let bytes = png(7, 5);
        let h = inspect(&bytes, ImageFormat::Png, 100).unwrap();
        assert_eq!((h.width, h.height), (7, 5));
        assert_eq!(decode(&bytes, &h).unwrap().width(), 7);
    }

    #[test]
    fn too_many_pixels_are_refused_before_decoding() {
        let e = inspect(&png(20, 20), ImageFormat::Png, 399).unwrap_err();
        assert!(matches!(e, ImageProblem::TooManyPixels { pixels: 400, .. }), "{e}");
    }

    #[test]
    fn truncated_and_mislabelled_files_are_refused() {
        let bytes = png(32, 32);
        let cut = &bytes[..bytes.len() - 30];
        let h = inspect(cut, ImageFormat::Png, 10_000).unwrap();
        assert!(matches!(decode(cut, &h), Err(ImageProblem::BadData { .. })));
        assert!(matches!(
            inspect(&bytes, ImageFormat::Jpeg, 10_000),
            Err(ImageProblem::WrongType { .. })
        ));
        assert!(matches!(
            inspect(&bytes[..12], ImageFormat::Png, 10_000),
            Err(ImageProblem::BadHeader { .. })
        ));
        assert!(format_of_content_type(Some("text/plain")).is_err());
        assert_eq!(format_of_content_type(Some("image/PNG; q=1")), Ok(ImageFormat::Png));
    }
}
