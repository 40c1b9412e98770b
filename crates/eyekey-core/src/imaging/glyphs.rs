//! A 5×7 bitmap font for rendering test documents (PIN slips, codes, short lines of text) without a font file.

use image::{Rgb, RgbImage};

/// 5×7 glyphs: each row is 5 bits, most significant bit on the left.
fn glyph(c: char) -> Option<[u8; 7]> {
    Some(match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        ',' => [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08],
        '#' => [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A],
        ' ' => [0; 7],
        _ => return None,
    })
}

/// Where one character of [`render_text`]'s layout is drawn: its glyph's top-left corner and the scale, in
/// document pixels; the glyph covers 5·scale × 7·scale pixels of a 6·scale × 9·scale character cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlyphCell {
    /// The character.
    pub ch: char,
    /// Line index.
    pub line: usize,
    /// Left edge of the glyph, document pixels (may lie outside the image when the text does not fit).
    pub x: i64,
    /// Top edge of the glyph, document pixels.
    pub y: i64,
    /// Pixels per font dot.
    pub scale: u32,
}

/// The layout [`render_text`] draws: every character of every line (spaces included) with its position.
pub fn text_cells(lines: &[&str], width: u32, height: u32, scale: u32) -> Vec<GlyphCell> {
    let s = scale.max(1);
    let line_h = 9 * s;
    let total_h = line_h * lines.len() as u32;
    let top = height.saturating_sub(total_h) / 2 + s;
    let mut cells = Vec::new();
    for (k, line) in lines.iter().enumerate() {
        let n = line.chars().count() as u32;
        let line_w = n * 6 * s;
        let left = width.saturating_sub(line_w) / 2 + s / 2;
        for (ci, ch) in line.chars().enumerate() {
            cells.push(GlyphCell {
                ch,
                line: k,
                x: left as i64 + (ci as i64 * 6) * s as i64,
                y: top as i64 + (k as i64) * line_h as i64,
                scale: s,
            });
        }
    }
    cells
}

/// Whether the font has a glyph for `c` (letters are drawn in upper case).
pub fn has_glyph(c: char) -> bool {
    glyph(c).is_some()
}

/// Draws character `c` black with its glyph's top-left corner at (x, y) and `scale` pixels per font dot;
/// characters without a glyph draw nothing.
pub fn draw_glyph(img: &mut RgbImage, c: char, x: i64, y: i64, scale: u32) {
    let Some(rows) = glyph(c) else { return };
    let s = scale.max(1) as i64;
    let (w, h) = (img.width() as i64, img.height() as i64);
    for (ry, bits) in rows.iter().enumerate() {
        for rx in 0..5i64 {
            if bits & (0x10 >> rx) == 0 {
                continue;
            }
            for dy in 0..s {
                for dx in 0..s {
                    let (px, py) = (x + rx * s + dx, y + ry as i64 * s + dy);
                    if (0..w).contains(&px) && (0..h).contains(&py) {
                        img.put_pixel(px as u32, py as u32, Rgb([0, 0, 0]));
                    }
                }
            }
        }
    }
}

/// Renders lines of text, black on white, at `scale` pixels per font dot, into a `width`×`height` image
/// (text centred). Characters without a glyph are drawn as blanks.
pub fn render_text(lines: &[&str], width: u32, height: u32, scale: u32) -> RgbImage {
    let mut img = RgbImage::from_pixel(width, height, Rgb([255, 255, 255]));
    for c in text_cells(lines, width, height, scale) {
        draw_glyph(&mut img, c.ch, c.x, c.y, c.scale);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_dark_text_inside_the_image() {
        let img = render_text(&["PIN 4821"], 100, 40, 2);
        let dark = img.pixels().filter(|p| p[0] == 0).count();
        assert!(dark > 50 && dark < 100 * 40 / 2, "{dark}");
        // The border stays white.
        assert!((0..100).all(|x| img.get_pixel(x, 0)[0] == 255));
    }
}
