//! Documents in fonts eyekey does not draw itself, for calibrating and testing the judges on text the encoder
//! was not tuned on: TrueType fonts from Debian's packages (`fonts-dejavu-core`, `fonts-liberation2`;
//! `tests/fonts/install.sh` installs them), rasterised with `ab_glyph`, and the known-font attacker for each.

use std::path::{Path, PathBuf};

use ab_glyph::{Font, FontVec, PxScale, ScaleFont};
use anyhow::{bail, Context, Result};
use image::{Rgb, RgbImage};

use eyekey_core::evaluation::{DocumentText, KnownFontAttacker};

/// The fonts the calibration draws its documents in: eyekey's own 5×7 bitmap font, and TrueType fonts of
/// several designs (sans, serif, monospaced) from Debian's packages, by file name.
pub const CALIBRATION_FONTS: [&str; 6] = [
    "5x7",
    "DejaVuSans.ttf",
    "DejaVuSerif.ttf",
    "DejaVuSansMono.ttf",
    "LiberationSerif-Regular.ttf",
    "LiberationMono-Regular.ttf",
];

/// Where Debian puts the calibration's TrueType fonts.
const FONT_DIRS: [&str; 2] = [
    "/usr/share/fonts/truetype/dejavu",
    "/usr/share/fonts/truetype/liberation2",
];

/// A font a document can be drawn in: eyekey's 5×7 bitmap font or a TrueType font.
pub enum DocFont {
    /// `eyekey_core::imaging::glyphs`, at a whole number of pixels per font dot.
    Bitmap,
    /// A TrueType font.
    TrueType {
        /// Its file name.
        name: String,
        /// The font.
        font: Box<FontVec>,
    },
}

impl DocFont {
    /// The font called `name`: `5x7`, or the file name of a TrueType font in Debian's font directories.
    pub fn load(name: &str) -> Result<Self> {
        if name == "5x7" {
            return Ok(Self::Bitmap);
        }
        let path: PathBuf = FONT_DIRS
            .iter()
            .map(|d| Path::new(d).join(name))
            .find(|p| p.is_file())
            .with_context(|| {
                format!("no font {name} in {FONT_DIRS:?}: run `bash tests/fonts/install.sh` as root first")
            })?;
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let font = FontVec::try_from_vec(bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Self::TrueType {
            name: name.to_string(),
            font: Box::new(font),
        })
    }

    /// The font's name as in [`CALIBRATION_FONTS`].
    pub fn name(&self) -> &str {
        match self {
            Self::Bitmap => "5x7",
            Self::TrueType { name, .. } => name,
        }
    }
}

/// A document drawn in some font, and the known-font attacker that knows that font and layout.
pub struct DrawnText {
    /// The document, black on white.
    pub document: RgbImage,
    /// The attacker for its secret characters (the digits).
    pub attacker: KnownFontAttacker,
}

/// Draws `lines` (centred, black on white) on a `width`×`height` document in `font` at `size` (pixels per font
/// dot for the bitmap font, pixels per em for a TrueType font); the digits are secret, and the attacker reads
/// them on a `grid`-sized retinal grid.
pub fn draw_text(
    font: &DocFont,
    lines: &[&str],
    width: u32,
    height: u32,
    size: f64,
    grid: (u32, u32),
) -> Result<DrawnText> {
    match font {
        DocFont::Bitmap => {
            let scale = size.round().max(1.0) as u32;
            let document = eyekey_core::imaging::glyphs::render_text(lines, width, height, scale);
            let text = DocumentText {
                lines: lines.iter().map(|l| l.to_string()).collect(),
                scale,
                alphabet: "0123456789".into(),
            };
            let attacker = KnownFontAttacker::new(&text, width, height, grid.0, grid.1)?;
            Ok(DrawnText { document, attacker })
        }
        DocFont::TrueType { font, .. } => {
            let layout = Layout::of(font, lines, width, height, size as f32)?;
            let mut document = white(width, height);
            for g in &layout.glyphs {
                draw_glyph(font, &mut document, g.ch, g.pen, layout.scale);
            }
            let secret: Vec<&Placed> = layout.glyphs.iter().filter(|g| g.ch.is_ascii_digit()).collect();
            if secret.is_empty() {
                bail!("no digit in {lines:?}");
            }
            let alphabet: Vec<char> = ('0'..='9').collect();
            let cells: Vec<(char, [f64; 4])> = secret.iter().map(|g| (g.ch, g.cell)).collect();
            let attacker = KnownFontAttacker::from_drawn(&alphabet, &cells, (width, height), grid, |k, c| {
                let mut doc = white(width, height);
                draw_glyph(font, &mut doc, c, secret[k].pen, layout.scale);
                doc
            })?;
            Ok(DrawnText { document, attacker })
        }
    }
}

/// A glyph placed on the document.
struct Placed {
    ch: char,
    /// Pen position: left end of the baseline, pixels.
    pen: (f32, f32),
    /// Its cell: the advance by ascent to descent, x0, y0, x1, y1 in pixels.
    cell: [f64; 4],
}

/// Every glyph of `lines`, each line centred, the block centred vertically.
struct Layout {
    scale: PxScale,
    glyphs: Vec<Placed>,
}

impl Layout {
    fn of(font: &FontVec, lines: &[&str], width: u32, height: u32, px: f32) -> Result<Self> {
        let scale = PxScale::from(px);
        let scaled = font.as_scaled(scale);
        let (ascent, descent) = (scaled.ascent(), scaled.descent());
        let line_height = ascent - descent + scaled.line_gap();
        let block = line_height * lines.len() as f32 - scaled.line_gap();
        let mut baseline = (height as f32 - block) / 2.0 + ascent;
        let mut glyphs = Vec::new();
        for line in lines {
            let advance: f32 = line.chars().map(|c| scaled.h_advance(font.glyph_id(c))).sum();
            let mut x = (width as f32 - advance) / 2.0;
            if x < 0.0 || baseline - ascent < -0.5 || baseline - descent > height as f32 + 0.5 {
                bail!("{line:?} at {px} px does not fit a {width}×{height} document");
            }
            for ch in line.chars() {
                let a = scaled.h_advance(font.glyph_id(ch));
                glyphs.push(Placed {
                    ch,
                    pen: (x, baseline),
                    cell: [
                        x as f64,
                        (baseline - ascent) as f64,
                        (x + a) as f64,
                        (baseline - descent) as f64,
                    ],
                });
                x += a;
            }
            baseline += line_height;
        }
        Ok(Self { scale, glyphs })
    }
}

fn white(width: u32, height: u32) -> RgbImage {
    RgbImage::from_pixel(width, height, Rgb([255, 255, 255]))
}

/// Draws `ch` with its pen at `pen`: ink darkens each pixel by the glyph's coverage of it.
fn draw_glyph(font: &FontVec, img: &mut RgbImage, ch: char, pen: (f32, f32), scale: PxScale) {
    let glyph = font
        .glyph_id(ch)
        .with_scale_and_position(scale, ab_glyph::point(pen.0, pen.1));
    let Some(outlined) = font.outline_glyph(glyph) else {
        return;
    };
    let bounds = outlined.px_bounds();
    outlined.draw(|gx, gy, coverage| {
        let (x, y) = (bounds.min.x as i64 + gx as i64, bounds.min.y as i64 + gy as i64);
        if x < 0 || y < 0 || x >= img.width() as i64 || y >= img.height() as i64 {
            return;
        }
        let p = img.get_pixel_mut(x as u32, y as u32);
        let v = (p[0] as f32 * (1.0 - coverage.clamp(0.0, 1.0))).round() as u8;
        *p = Rgb([v, v, v]);
    });
}

/// How a calibration document is laid out: its lines (`#` stands for the secret digits) and how much of the
/// document's width its widest line fills.
#[derive(Clone, Copy, Debug)]
pub struct TextLayout {
    /// The lines, `#` for the PIN.
    pub lines: &'static [&'static str],
    /// Fraction of the width the widest line fills (at most; the height may limit it).
    pub fill: f64,
}

/// The calibration's layouts: the PIN alone, large and small, and under a "PIN" label, large and small.
pub const CALIBRATION_LAYOUTS: [TextLayout; 4] = [
    TextLayout {
        lines: &["#"],
        fill: 0.85,
    },
    TextLayout {
        lines: &["#"],
        fill: 0.45,
    },
    TextLayout {
        lines: &["PIN", "#"],
        fill: 0.85,
    },
    TextLayout {
        lines: &["PIN", "#"],
        fill: 0.5,
    },
];

impl TextLayout {
    /// A short name for tables and CSV: "1 line 85 %".
    pub fn name(&self) -> String {
        format!(
            "{} line{} {:.0} %",
            self.lines.len(),
            if self.lines.len() > 1 { "s" } else { "" },
            100.0 * self.fill
        )
    }
}

/// `layout` with `pin` for its `#`, drawn in `font` on a `width`×`height` document as large as the layout asks
/// (and the document allows), read on a `grid`-sized retinal grid.
pub fn draw_layout(
    font: &DocFont,
    layout: &TextLayout,
    pin: &str,
    width: u32,
    height: u32,
    grid: (u32, u32),
) -> Result<DrawnText> {
    let lines: Vec<String> = layout.lines.iter().map(|l| l.replace('#', pin)).collect();
    draw_filling(font, &lines, layout.fill, width, height, grid)
}

/// `lines` drawn in `font` on a `width`×`height` document, the widest filling `fill` of its width (at most; the
/// height may limit it), read on a `grid`-sized retinal grid; the digits are secret.
pub fn draw_filling(
    font: &DocFont,
    lines: &[String],
    fill: f64,
    width: u32,
    height: u32,
    grid: (u32, u32),
) -> Result<DrawnText> {
    let lines: Vec<&str> = lines.iter().map(String::as_str).collect();
    let widest = lines.iter().map(|l| l.chars().count()).max().unwrap_or(1);
    let size = match font {
        DocFont::Bitmap => {
            // A 5×7 glyph and a dot of spacing per character; seven dots and two of leading per line.
            let by_width = fill * width as f64 / (6 * widest) as f64;
            let by_height = 0.9 * height as f64 / (9 * lines.len()) as f64;
            by_width.min(by_height).round().max(1.0)
        }
        DocFont::TrueType { font, .. } => {
            let em = font.as_scaled(PxScale::from(1.0));
            let advance = lines
                .iter()
                .map(|l| l.chars().map(|c| em.h_advance(font.glyph_id(c))).sum::<f32>())
                .fold(0.0f32, f32::max) as f64;
            let tall = (em.ascent() - em.descent()) as f64 * lines.len() as f64
                + em.line_gap() as f64 * (lines.len() as f64 - 1.0);
            (fill * width as f64 / advance).min(0.95 * height as f64 / tall)
        }
    };
    draw_text(font, &lines, width, height, size, grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_truetype_pin_is_read_right_from_its_own_document_and_wrong_from_another() {
        // DejaVu Sans: Debian's fonts-dejavu-core, which tests/fonts/install.sh installs (.ci/run runs it).
        let font = DocFont::load("DejaVuSans.ttf").expect("tests/fonts/install.sh installs DejaVu Sans");
        for layout in CALIBRATION_LAYOUTS {
            let drawn = draw_layout(&font, &layout, "4821", 56, 56, (56, 56)).unwrap();
            let lum = eyekey_core::evaluation::image_luminance(&drawn.document);
            let read = drawn.attacker.read(&lum);
            assert!(
                read.correct && read.text == "4821" && read.margin > 0.1,
                "{layout:?}: {read:?}"
            );
            let other = draw_layout(&font, &layout, "7093", 56, 56, (56, 56)).unwrap();
            let read = drawn
                .attacker
                .read(&eyekey_core::evaluation::image_luminance(&other.document));
            assert_eq!(read.text, "7093", "{layout:?}: the attacker reads what is drawn");
            assert!(!read.correct);
        }
    }
}

#[cfg(test)]
mod domain_tests {
    use super::*;

    #[test]
    fn the_legibility_judges_domain_starts_at_the_calibrations_smallest_characters() {
        // The calibration's documents: every font and layout, on its 56×56 grid, one pixel per hole.
        let mut smallest = f64::INFINITY;
        for name in super::super::fonts::CALIBRATION_FONTS {
            let font = DocFont::load(name).expect("tests/fonts/install.sh installs the calibration's fonts");
            for layout in CALIBRATION_LAYOUTS {
                let drawn = draw_layout(&font, &layout, "4821", 56, 56, (56, 56)).unwrap();
                let h = eyekey_core::evaluation::text_height_on_grid(&drawn.document, 56).unwrap();
                eprintln!("{name} {}: {h:.1} px", layout.name());
                smallest = smallest.min(h);
            }
        }
        let min = eyekey_core::evaluation::MIN_JUDGED_TEXT_PX;
        assert!(
            (min..min + 1.0).contains(&smallest),
            "the calibration's smallest characters are {smallest:.1} px tall"
        );
    }
}
