//! The document as the evaluation sees it: luminance on the retinal grid at the objective's level.

use crate::evaluation::{
    denoised, image_luminance, ink_box, legibility_of_denoised, luminance, ncc, psnr, ssim, ViewScore, INK_MARGIN,
};
use crate::imaging;
use crate::physics::observer::Observer;
use image::RgbImage;

/// The document as the evaluation sees it: luminance on the retinal grid and the objective's level.
pub struct Reference {
    /// Document luminance (linear, 0..1), row-major on the retinal grid.
    pub document: Vec<f32>,
    /// Grid width.
    pub width: usize,
    /// Grid height.
    pub height: usize,
    /// The objective level (fraction of the display white the target was asked to see).
    pub level: f64,
    /// Legibility threshold.
    pub threshold: f64,
    /// The known-font attacker, when the document's text is known.
    pub known_font: Option<crate::evaluation::KnownFontAttacker>,
    /// The box around the document's ink where legibility is measured (x0, y0, x1, y1).
    pub ink_box: (usize, usize, usize, usize),
}

impl Reference {
    /// From an sRGB document resized to the retinal grid.
    pub fn new(document: &RgbImage, width: u32, height: u32, level: f64, threshold: f64) -> Self {
        let resized = imaging::resize(document, width, height);
        let document = image_luminance(&resized);
        let ink_box = ink_box(&document, width as usize, height as usize, INK_MARGIN);
        Self {
            document,
            width: width as usize,
            height: height as usize,
            level,
            threshold,
            known_font: None,
            ink_box,
        }
    }

    /// The same reference with the known-font attacker reading every view too.
    pub fn with_known_font(mut self, attacker: crate::evaluation::KnownFontAttacker) -> Self {
        self.known_font = Some(attacker);
        self
    }

    /// Scores a luminance view; `white_luminance` is the viewer's luminance of the display's full white.
    pub fn score(&self, label: &str, view_luminance: &[f32], white_luminance: f64) -> ViewScore {
        // Denoised once, for the legibility score and the known-font attacker alike.
        let denoised = denoised(view_luminance, self.width, self.height);
        let leg = legibility_of_denoised(&denoised, &self.document, self.width, self.ink_box);
        let norm: Vec<f32> = view_luminance
            .iter()
            .map(|v| (*v as f64 / white_luminance) as f32)
            .collect();
        let objective: Vec<f32> = self.document.iter().map(|v| (*v as f64 * self.level) as f32).collect();
        let known_font = self.known_font.as_ref().map(|a| a.read_denoised(&denoised));
        let read = known_font.as_ref().is_some_and(|k| k.correct);
        ViewScore {
            label: label.to_string(),
            legibility: leg,
            ncc: ncc(view_luminance, &self.document),
            psnr_db: psnr(&norm, &objective, self.level),
            ssim: ssim(&norm, &objective, self.width, self.height, self.level),
            // Where the text is known the matched filter is the judge (docs/design.md §4); elsewhere the
            // calibrated threshold.
            readable: if known_font.is_some() {
                read
            } else {
                leg >= self.threshold
            },
            known_font,
        }
    }

    /// Scores what `observer` sees of light field `l`; returns the score and the picture.
    pub fn score_observer(&self, label: &str, observer: &Observer, l: &[f32]) -> (ViewScore, RgbImage) {
        let view = observer.view(l);
        (self.score_lms(label, &view, observer.white), observer.picture(&view))
    }

    /// Scores an LMS view (`[r·3 + a]`) seen by a viewer whose display white is `white_lms`.
    pub fn score_lms(&self, label: &str, view: &[f32], white_lms: [f64; 3]) -> ViewScore {
        let white = crate::evaluation::luminance_of(white_lms);
        self.score(label, &luminance(view), white)
    }
}
