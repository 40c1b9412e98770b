//! The document as the evaluation sees it: luminance on the retinal grid at the objective's level.

use crate::evaluation::{
    denoised, image_luminance, ink_box, legibility_of_denoised, luminance, ncc, psnr, ssim, TargetJudge, TargetReading,
    ViewScore, INK_MARGIN, MIN_JUDGED_TEXT_PX, READS_THRESHOLD,
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
    /// The learned reader, when one was trained on the document's layout.
    pub learned: Option<crate::evaluation::BoundReader>,
    /// The box around the document's ink where legibility is measured (x0, y0, x1, y1).
    pub ink_box: (usize, usize, usize, usize),
    /// How tall the document's characters are on the grid ([`text_height_on_grid`](crate::evaluation::text_height_on_grid)):
    /// the legibility judge's domain.
    pub text_height: Option<f64>,
}

impl Reference {
    /// From an sRGB document resized to the retinal grid.
    pub fn new(document: &RgbImage, width: u32, height: u32, level: f64, threshold: f64) -> Self {
        let text_height = crate::evaluation::text_height_on_grid(document, height);
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
            learned: None,
            ink_box,
            text_height,
        }
    }

    /// The same reference with the known-font attacker reading every view too, and the learned reader where one
    /// was trained on the document's layout ([`LearnedReader::for_document`](crate::evaluation::LearnedReader)).
    pub fn with_known_font(mut self, attacker: crate::evaluation::KnownFontAttacker) -> Self {
        self.learned =
            crate::evaluation::LearnedReader::for_document(&attacker, (self.width as u32, self.height as u32));
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
        let learned = self.learned.as_ref().map(|r| r.read(view_luminance));
        // Either reader reading every secret character reads the view.
        let read = known_font.as_ref().is_some_and(|k| k.correct) || learned.as_ref().is_some_and(|r| r.correct);
        ViewScore {
            label: label.to_string(),
            legibility: leg,
            ncc: ncc(view_luminance, &self.document),
            psnr_db: psnr(&norm, &objective, self.level),
            focus_d: None,
            ssim: ssim(&norm, &objective, self.width, self.height, self.level),
            // Where the text is known the matched filter and, for a layout one was trained on, the learned reader
            // are the judges (docs/design.md §4); elsewhere the calibrated threshold.
            readable: if known_font.is_some() {
                read
            } else {
                leg >= self.threshold
            },
            known_font,
            learned,
        }
    }

    /// Whether the target reads a view scored by [`Reference::score`], by the target's bar: the known-font
    /// attacker reads every secret character with a lead of at least `margin` where the text is known, else the
    /// legibility reaches [`READS_THRESHOLD`] (a view between [`DEFAULT_THRESHOLD`](crate::evaluation::DEFAULT_THRESHOLD)
    /// and it is neither secret nor read).
    pub fn target_reading(&self, score: &ViewScore, margin: f64) -> TargetReading {
        match &score.known_font {
            Some(k) => TargetReading {
                judge: TargetJudge::KnownFont,
                reads: k.correct && k.margin >= margin,
                score: k.margin,
                bar: margin,
            },
            // Characters smaller than any the reads bar was calibrated on: no judge is right here, and the
            // verdict is never "reads".
            None => match self.text_height {
                Some(h) if h < MIN_JUDGED_TEXT_PX => TargetReading {
                    judge: TargetJudge::Unknown,
                    reads: false,
                    score: h,
                    bar: MIN_JUDGED_TEXT_PX,
                },
                _ => TargetReading {
                    judge: TargetJudge::Legibility,
                    reads: score.legibility >= READS_THRESHOLD,
                    score: score.legibility,
                    bar: READS_THRESHOLD,
                },
            },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::{KnownFontRead, DEFAULT_THRESHOLD};

    fn score(legibility: f64, known_font: Option<KnownFontRead>) -> ViewScore {
        ViewScore {
            label: "target".into(),
            legibility,
            ncc: 0.0,
            psnr_db: 0.0,
            focus_d: None,
            learned: None,
            ssim: 0.0,
            readable: known_font
                .as_ref()
                .map_or(legibility >= DEFAULT_THRESHOLD, |k| k.correct),
            known_font,
        }
    }

    fn read(correct: bool, margin: f64) -> KnownFontRead {
        KnownFontRead {
            text: "4821".into(),
            correct,
            characters_right: if correct { 4 } else { 3 },
            characters: 4,
            confidence: 0.5,
            margin,
            chance: 1e-4,
        }
    }

    #[test]
    fn the_target_is_held_to_the_bar_at_which_a_reader_does_read_not_the_one_at_which_somebody_might() {
        let reference = Reference::new(&RgbImage::new(8, 8), 8, 8, 0.5, DEFAULT_THRESHOLD);
        // Without a text hint: a view somebody might read (0.30 ≥ 0.26) is not one the target reads.
        let might = score(0.30, None);
        assert!(might.readable);
        let r = reference.target_reading(&might, 0.0);
        assert_eq!(
            (r.judge, r.reads, r.bar),
            (TargetJudge::Legibility, false, READS_THRESHOLD)
        );
        assert!((r.margin() - (0.30 - READS_THRESHOLD)).abs() < 1e-12);
        assert!(reference.target_reading(&score(READS_THRESHOLD, None), 0.0).reads);
        assert_eq!(
            reference.target_reading(&score(0.30, None), 0.0).describe(),
            "does not read it (no text hint: legibility 0.30, read from 0.80)"
        );
        // With one: the known-font attacker decides, whatever the legibility, with the margin asked.
        let r = reference.target_reading(&score(0.2, Some(read(true, 0.03))), 0.02);
        assert_eq!(
            (r.judge, r.reads, r.score, r.bar),
            (TargetJudge::KnownFont, true, 0.03, 0.02)
        );
        assert!(
            !reference
                .target_reading(&score(0.9, Some(read(true, 0.01))), 0.02)
                .reads
        );
        assert!(
            !reference
                .target_reading(&score(0.9, Some(read(false, -0.01))), 0.0)
                .reads
        );
    }
}
