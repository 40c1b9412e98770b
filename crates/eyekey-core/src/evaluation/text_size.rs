//! How large a document's characters land on the retina: the domain of the legibility judge. The reads bar of
//! legibility ([`READS_THRESHOLD`](crate::evaluation::READS_THRESHOLD)) is calibrated on documents whose
//! characters are at least [`MIN_JUDGED_TEXT_PX`] retinal pixels tall (docs/legibility-calibration.md); below
//! that a view can resemble the document closely (legibility 0.9) while no reader makes out a character, because
//! the document itself, at the display's resolution, is no longer text anyone reads.

use image::RgbImage;

/// The smallest character height, in retinal pixels (one per hole), of the legibility calibration's documents
/// (eyekey's 5×7 font at one pixel per dot, and the TrueType fonts' digits at the smallest layout): below it the
/// legibility judge has never been checked, and on two lines of DejaVu Sans Mono about 4 pixels tall it passed
/// views at legibility 0.86–0.95 that the known-font attacker misread (docs/experiments.md §0).
pub const MIN_JUDGED_TEXT_PX: f64 = 7.0;

/// The typical height of `document`'s characters on a retinal grid `grid_height` pixels tall (the document is
/// resampled to the grid): the median height of its ink's connected components (8-connected, pixels darker than
/// halfway between the document's darkest and lightest, at least 3 pixels), scaled by `grid_height` over the
/// document's height. None when the document has no ink (less than 20 % contrast, or no component).
pub fn text_height_on_grid(document: &RgbImage, grid_height: u32) -> Option<f64> {
    let (w, h) = (document.width() as usize, document.height() as usize);
    let lum = crate::evaluation::image_luminance(document);
    let (lo, hi) = lum.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
        (lo.min(v), hi.max(v))
    });
    if hi - lo < 0.2 || (hi - lo).is_nan() {
        return None;
    }
    let mid = (lo + hi) / 2.0;
    let mut ink: Vec<bool> = lum.iter().map(|&v| v < mid).collect();
    let mut heights = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !ink[start] {
            continue;
        }
        ink[start] = false;
        stack.push(start);
        let (mut top, mut bottom, mut area) = (usize::MAX, 0, 0usize);
        while let Some(p) = stack.pop() {
            let (x, y) = (p % w, p / w);
            top = top.min(y);
            bottom = bottom.max(y);
            area += 1;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let q = ny as usize * w + nx as usize;
                    if ink[q] {
                        ink[q] = false;
                        stack.push(q);
                    }
                }
            }
        }
        if area >= 3 {
            heights.push(bottom - top + 1);
        }
    }
    if heights.is_empty() {
        return None;
    }
    heights.sort_unstable();
    let median = heights[heights.len() / 2] as f64;
    Some(median * f64::from(grid_height) / h as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_height_of_a_5x7_line_is_seven_dots_scaled_to_the_grid() {
        // "4821" at 4 pixels per dot: each digit's ink is 7 dots, 28 pixels, tall; on a grid a quarter of the
        // page's height, 7 pixels.
        let doc = crate::imaging::glyphs::render_text(&["4821"], 128, 128, 4);
        assert_eq!(text_height_on_grid(&doc, 128), Some(28.0));
        assert_eq!(text_height_on_grid(&doc, 32), Some(7.0));
        // A blank page has no text; a speck of two pixels is not a character.
        let mut blank = RgbImage::from_pixel(64, 64, image::Rgb([255, 255, 255]));
        assert_eq!(text_height_on_grid(&blank, 64), None);
        blank.put_pixel(3, 3, image::Rgb([0, 0, 0]));
        blank.put_pixel(4, 4, image::Rgb([0, 0, 0]));
        assert_eq!(text_height_on_grid(&blank, 64), None);
    }

    #[test]
    fn without_a_hint_a_view_of_text_below_the_judges_domain_is_never_called_read() {
        use crate::evaluation::{Reference, TargetJudge, DEFAULT_THRESHOLD};
        // The document itself, seen perfectly: legibility 1. On a grid where its characters are 7 pixels tall
        // the legibility judge says it is read; on one where they are 3.5, the verdict is unknown, never "reads".
        let doc = crate::imaging::glyphs::render_text(&["4821"], 128, 128, 4);
        for (grid, judge, reads) in [(32, TargetJudge::Legibility, true), (16, TargetJudge::Unknown, false)] {
            let reference = Reference::new(&doc, grid, grid, 1.0, DEFAULT_THRESHOLD);
            let view = reference.document.clone();
            let reading = reference.target_reading(&reference.score("target", &view, 1.0), 0.0);
            assert_eq!((reading.judge, reading.reads), (judge, reads), "{grid}: {reading:?}");
        }
        let unknown = Reference::new(&doc, 16, 16, 1.0, DEFAULT_THRESHOLD);
        let reading = unknown.target_reading(&unknown.score("target", &unknown.document, 1.0), 0.0);
        assert_eq!(reading.score, 3.5);
        assert!(
            reading.describe().starts_with("may or may not read it (unknown"),
            "{}",
            reading.describe()
        );
    }
}
