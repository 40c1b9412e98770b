//! The known-font attacker (docs/design.md §4, "The judge"): a matched filter per character cell for a
//! document whose alphabet, font and layout are known.
//!
//! For every secret cell (a character of the document's text that belongs to the alphabet) the attacker holds a
//! template per candidate glyph: the document with only that glyph drawn, resized to the retinal grid exactly as
//! the document is ([`crate::imaging::resize`]), cropped to the character's 6×9-dot cell. It reads the view after
//! each denoising strength of [`crate::evaluation::DENOISE_SIGMAS`] and in both polarities (a negative image is as readable as a
//! positive one) and with the whole text moved by up to ±1 grid pixel either way: per cell, the candidate with
//! the highest normalised cross-correlation. Of those (denoising, shift, polarity) readings it answers with the
//! one it is most confident of (the highest mean winning correlation): one answer, so its chance of guessing right is |alphabet|^−n for n secret
//! cells. The view is read when every secret character is right.

use image::{Rgb, RgbImage};
use serde::{Deserialize, Serialize};

use crate::evaluation::{image_luminance, ncc};
use crate::imaging::{self, glyphs};

/// The text of a document drawn by [`glyphs::render_text`], and which of its characters are secret.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct DocumentText {
    /// The lines, as rendered; in a hint, a secret character may be written `*` and is then read from the
    /// document (see [`DocumentText::resolve`]).
    pub lines: Vec<String>,
    /// Pixels per font dot, as rendered.
    pub scale: u32,
    /// Characters an attacker must tell apart (e.g. "0123456789" for a PIN); the text's other characters are
    /// known to the attacker (labels such as "PIN").
    pub alphabet: String,
}

/// A secret character of a layout hint whose value is read from the document itself (see
/// [`DocumentText::resolve`]): a hint can then describe a PIN slip's layout without holding the PIN.
pub const MASK: char = '*';

impl DocumentText {
    /// Checks the hint's size: 1–16 lines of at most 64 characters, 1–64 pixels per font dot, an alphabet of
    /// at most 64 characters.
    pub fn validate(&self) -> Result<(), KnownFontError> {
        if self.lines.is_empty() || self.lines.len() > 16 || self.lines.iter().any(|l| l.chars().count() > 64) {
            return Err(KnownFontError::Layout("1 to 16 lines of at most 64 characters".into()));
        }
        if !(1..=64).contains(&self.scale) {
            return Err(KnownFontError::Layout(format!(
                "scale must be within 1..=64, got {}",
                self.scale
            )));
        }
        if self.alphabet.chars().count() > 64 {
            return Err(KnownFontError::Alphabet("at most 64 characters".into()));
        }
        Ok(())
    }

    /// The hint with every secret character (one of the alphabet) written [`MASK`]: the layout without the
    /// secret, which [`DocumentText::resolve`] reads back from the document.
    pub fn masked(&self) -> DocumentText {
        let alphabet: Vec<char> = self.alphabet.chars().map(|c| c.to_ascii_uppercase()).collect();
        DocumentText {
            lines: self
                .lines
                .iter()
                .map(|l| {
                    l.chars()
                        .map(|c| {
                            if alphabet.contains(&c.to_ascii_uppercase()) {
                                MASK
                            } else {
                                c
                            }
                        })
                        .collect()
                })
                .collect(),
            ..self.clone()
        }
    }

    /// Checks, without drawing anything, that the hint can describe a document in eyekey's font: its size
    /// ([`DocumentText::validate`]), an alphabet of two or more characters the font draws, and at least one secret
    /// character in the text.
    pub fn check_cheaply(&self) -> Result<(), KnownFontError> {
        self.validate()?;
        let alphabet: Vec<char> = self.alphabet.chars().map(|c| c.to_ascii_uppercase()).collect();
        if alphabet.len() < 2 {
            return Err(KnownFontError::Alphabet("needs at least two characters".into()));
        }
        if let Some(c) = alphabet.iter().find(|c| !glyphs::has_glyph(**c) || **c == ' ') {
            return Err(KnownFontError::Alphabet(format!("the font has no glyph for '{c}'")));
        }
        let secret = |c: char| c == MASK || alphabet.contains(&c.to_ascii_uppercase());
        if !self.lines.iter().any(|l| l.chars().any(secret)) {
            return Err(KnownFontError::NothingSecret);
        }
        Ok(())
    }

    /// The hint with every [`MASK`] replaced by the character the document shows there, and every secret
    /// character checked against the document: the known-font attacker reads the document itself (at its own
    /// resolution) and must find each cell's glyph with a correlation of at least 0.9.
    pub fn resolve(&self, document: &RgbImage) -> Result<DocumentText, KnownFontError> {
        self.validate()?;
        let alphabet: Vec<char> = self.alphabet.chars().map(|c| c.to_ascii_uppercase()).collect();
        let placeholder = *alphabet
            .first()
            .ok_or_else(|| KnownFontError::Alphabet("is empty".into()))?;
        let probe = DocumentText {
            lines: self
                .lines
                .iter()
                .map(|l| l.chars().map(|c| if c == MASK { placeholder } else { c }).collect())
                .collect(),
            ..self.clone()
        };
        let (w, h) = document.dimensions();
        let attacker = KnownFontAttacker::new(&probe, w, h, w, h)?;
        let lum = image_luminance(document);
        let mut read = Vec::with_capacity(attacker.cells.len());
        for cell in &attacker.cells {
            let scores = attacker
                .cell_scores(cell, &lum, 0, 0)
                .expect("an unshifted cell lies inside the document");
            let (k, best) = scores
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .expect("an alphabet has two characters or more");
            if *best < 0.9 {
                return Err(KnownFontError::DoesNotMatch(format!(
                    "no character of the alphabet is drawn at secret character {} (best correlation {best:.2})",
                    read.len()
                )));
            }
            read.push(attacker.alphabet[k]);
        }
        // Secret cells come in text order; masks take what was read, given characters must agree with it.
        let mut next = read.into_iter();
        let mut lines = Vec::with_capacity(self.lines.len());
        for line in &self.lines {
            let mut out = String::new();
            for c in line.chars() {
                let secret = c == MASK || attacker.alphabet.contains(&c.to_ascii_uppercase());
                if !secret {
                    out.push(c);
                    continue;
                }
                let shown = next.next().expect("one reading per secret cell");
                if c != MASK && c.to_ascii_uppercase() != shown {
                    return Err(KnownFontError::DoesNotMatch(format!(
                        "the hint says '{c}' where the document shows '{shown}'"
                    )));
                }
                out.push(shown);
            }
            lines.push(out);
        }
        Ok(DocumentText { lines, ..self.clone() })
    }
}

/// Why a known-font attacker cannot be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum KnownFontError {
    /// The alphabet has a character the font cannot draw, or fewer than two characters.
    #[error("alphabet: {0}")]
    Alphabet(String),
    /// The hint's lines or scale are out of range.
    #[error("layout: {0}")]
    Layout(String),
    /// The hint does not describe the document.
    #[error("the hint does not match the document: {0}")]
    DoesNotMatch(String),
    /// No character of the text is in the alphabet.
    #[error("the text has no character of the alphabet: nothing is secret")]
    NothingSecret,
    /// A secret character's cell does not lie inside the document.
    #[error("character {index} ('{ch}') lies outside the {width}×{height} document")]
    OutsideDocument {
        /// Its index among the text's characters.
        index: usize,
        /// The character.
        ch: char,
        /// Document width.
        width: u32,
        /// Document height.
        height: u32,
    },
}

/// One secret character's cell on the retinal grid and its candidates' templates.
#[derive(Clone, Debug)]
struct Cell {
    truth: char,
    /// Cell box on the grid: x0, y0, width, height.
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    /// One template (luminance, row-major in the box) per alphabet character.
    templates: Vec<Vec<f32>>,
}

/// A character cell's box on the retinal grid: x0, y0, width, height.
pub type CellBox = (usize, usize, usize, usize);

/// What the attacker made of one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct KnownFontRead {
    /// The secret characters as read, in text order.
    pub text: String,
    /// Every secret character right.
    pub correct: bool,
    /// How many secret characters are right.
    pub characters_right: u32,
    /// Secret characters in the document.
    pub characters: u32,
    /// The reading's mean winning correlation (the attacker's confidence).
    pub confidence: f64,
    /// At the reading's shift, denoising and polarity: the smallest lead, over the secret cells, of the true
    /// glyph's correlation over the best other candidate's (negative when a character is read wrong). How far
    /// the view is from being misread.
    pub margin: f64,
    /// Probability of reading right by guessing, |alphabet|^−n.
    pub chance: f64,
}

/// The matched-filter attacker for one document on one retinal grid.
#[derive(Clone, Debug)]
pub struct KnownFontAttacker {
    alphabet: Vec<char>,
    cells: Vec<Cell>,
    width: usize,
    height: usize,
}

impl KnownFontAttacker {
    /// The attacker for `text` drawn on a `doc_width`×`doc_height` document, reading views on a
    /// `grid_width`×`grid_height` retinal grid.
    pub fn new(
        text: &DocumentText,
        doc_width: u32,
        doc_height: u32,
        grid_width: u32,
        grid_height: u32,
    ) -> Result<Self, KnownFontError> {
        let mut alphabet: Vec<char> = text.alphabet.chars().map(|c| c.to_ascii_uppercase()).collect();
        alphabet.sort_unstable();
        alphabet.dedup();
        if alphabet.len() < 2 {
            return Err(KnownFontError::Alphabet("needs at least two characters".into()));
        }
        if let Some(c) = alphabet.iter().find(|c| !glyphs::has_glyph(**c) || **c == ' ') {
            return Err(KnownFontError::Alphabet(format!("the font has no glyph for '{c}'")));
        }
        let lines: Vec<&str> = text.lines.iter().map(String::as_str).collect();
        let layout = glyphs::text_cells(&lines, doc_width, doc_height, text.scale);
        let mut secret = Vec::new();
        for (index, g) in layout.iter().enumerate() {
            let ch = g.ch.to_ascii_uppercase();
            if !alphabet.contains(&ch) {
                continue;
            }
            // The character's cell: 6×9 font dots around its 5×7 glyph (half a dot either side, one above and
            // one below), in document pixels.
            let s = g.scale as f64;
            let (dx0, dy0) = (g.x as f64 - 0.5 * s, g.y as f64 - s);
            let (dx1, dy1) = (dx0 + 6.0 * s, dy0 + 9.0 * s);
            if dx0 < 0.0 || dy0 < 0.0 || dx1 > doc_width as f64 || dy1 > doc_height as f64 {
                return Err(KnownFontError::OutsideDocument {
                    index,
                    ch: g.ch,
                    width: doc_width,
                    height: doc_height,
                });
            }
            secret.push((ch, [dx0, dy0, dx1, dy1], (g.x, g.y, g.scale)));
        }
        let cells: Vec<(char, [f64; 4])> = secret.iter().map(|(c, b, _)| (*c, *b)).collect();
        Self::from_drawn(
            &alphabet,
            &cells,
            (doc_width, doc_height),
            (grid_width, grid_height),
            |k, c| {
                let (x, y, scale) = secret[k].2;
                let mut doc = RgbImage::from_pixel(doc_width, doc_height, Rgb([255, 255, 255]));
                glyphs::draw_glyph(&mut doc, c, x, y, scale);
                doc
            },
        )
    }

    /// The attacker for a document in any font: `cells` are its secret characters (the character drawn and its
    /// cell's box on the document, x0, y0, x1, y1 in pixels), and `draw(k, c)` is the document with only character
    /// `c` drawn in cell `k`, black on white, `doc` pixels large; views are read on a `grid`-sized retinal grid.
    /// Each candidate's template is that drawing resized to the grid as the document is, cropped to the cell.
    pub fn from_drawn(
        alphabet: &[char],
        cells: &[(char, [f64; 4])],
        doc: (u32, u32),
        grid: (u32, u32),
        draw: impl Fn(usize, char) -> RgbImage,
    ) -> Result<Self, KnownFontError> {
        let mut alphabet = alphabet.to_vec();
        alphabet.sort_unstable();
        alphabet.dedup();
        if alphabet.len() < 2 {
            return Err(KnownFontError::Alphabet("needs at least two characters".into()));
        }
        let (fx, fy) = (grid.0 as f64 / doc.0 as f64, grid.1 as f64 / doc.1 as f64);
        let mut out = Vec::with_capacity(cells.len());
        for (k, &(truth, [dx0, dy0, dx1, dy1])) in cells.iter().enumerate() {
            if !alphabet.contains(&truth) {
                return Err(KnownFontError::Alphabet(format!(
                    "'{truth}' is drawn but not in the alphabet"
                )));
            }
            let x0 = (dx0.max(0.0) * fx).floor() as usize;
            let y0 = (dy0.max(0.0) * fy).floor() as usize;
            let x1 = ((dx1 * fx).ceil() as usize).min(grid.0 as usize);
            let y1 = ((dy1 * fy).ceil() as usize).min(grid.1 as usize);
            let (w, h) = (x1.saturating_sub(x0), y1.saturating_sub(y0));
            if w == 0 || h == 0 {
                return Err(KnownFontError::OutsideDocument {
                    index: k,
                    ch: truth,
                    width: doc.0,
                    height: doc.1,
                });
            }
            let templates = alphabet
                .iter()
                .map(|&c| {
                    let lum = image_luminance(&imaging::resize(&draw(k, c), grid.0, grid.1));
                    crop(&lum, grid.0 as usize, x0 as isize, y0 as isize, w, h)
                })
                .collect();
            out.push(Cell {
                truth,
                x0,
                y0,
                w,
                h,
                templates,
            });
        }
        if out.is_empty() {
            return Err(KnownFontError::NothingSecret);
        }
        Ok(Self {
            alphabet,
            cells: out,
            width: grid.0 as usize,
            height: grid.1 as usize,
        })
    }

    /// Secret characters in the document.
    pub fn characters(&self) -> usize {
        self.cells.len()
    }

    /// The secret characters in text order, each with its cell's box on the grid.
    pub fn secret(&self) -> Vec<(char, CellBox)> {
        self.cells.iter().map(|c| (c.truth, (c.x0, c.y0, c.w, c.h))).collect()
    }

    /// The candidates for each secret character, sorted.
    pub fn alphabet(&self) -> &[char] {
        &self.alphabet
    }

    /// What tells each secret cell's true glyph from the others: per cell, its box on the grid (x0, y0, width,
    /// height) and the true glyph's template minus the mean of the other candidates' (row-major in the box). A
    /// view whose cells are orthogonal to these, after the attacker's mean removal, gives the true glyph no edge.
    pub fn discriminants(&self) -> Vec<(CellBox, Vec<f32>)> {
        self.cells
            .iter()
            .map(|c| {
                let truth = self
                    .alphabet
                    .iter()
                    .position(|&a| a == c.truth)
                    .expect("the truth is a candidate");
                let others = (c.templates.len() - 1) as f32;
                let d = (0..c.w * c.h)
                    .map(|i| {
                        let rest: f32 = (0..c.templates.len())
                            .filter(|&k| k != truth)
                            .map(|k| c.templates[k][i])
                            .sum();
                        c.templates[truth][i] - rest / others
                    })
                    .collect();
                ((c.x0, c.y0, c.w, c.h), d)
            })
            .collect()
    }

    /// Probability of reading every secret character right by guessing.
    pub fn chance(&self) -> f64 {
        (self.alphabet.len() as f64).powi(-(self.cells.len() as i32))
    }

    /// Reads a luminance view (row-major on the grid).
    pub fn read(&self, view: &[f32]) -> KnownFontRead {
        assert_eq!(view.len(), self.width * self.height, "view size");
        self.read_denoised(&crate::evaluation::denoised(view, self.width, self.height))
    }

    /// Reads a view already denoised at each of [`crate::evaluation::DENOISE_SIGMAS`] ([`crate::evaluation::denoised`]).
    pub fn read_denoised(&self, denoised: &[Vec<f32>]) -> KnownFontRead {
        let mut best: Option<(f64, Vec<char>, f64)> = None;
        for v in denoised {
            assert_eq!(v.len(), self.width * self.height, "view size");
            for dy in -1isize..=1 {
                for dx in -1isize..=1 {
                    // The whole text moves together: per cell and candidate, the correlation at this shift.
                    let Some(scores) = self
                        .cells
                        .iter()
                        .map(|c| self.cell_scores(c, v, dx, dy))
                        .collect::<Option<Vec<_>>>()
                    else {
                        continue;
                    };
                    for polarity in [1.0, -1.0] {
                        let mut read = Vec::with_capacity(self.cells.len());
                        let mut total = 0.0;
                        let mut margin = f64::INFINITY;
                        for (cell, cell_scores) in self.cells.iter().zip(&scores) {
                            let (k, s) = cell_scores
                                .iter()
                                .map(|r| polarity * r)
                                .enumerate()
                                .fold((0, f64::NEG_INFINITY), |a, (k, s)| if s > a.1 { (k, s) } else { a });
                            read.push(self.alphabet[k]);
                            total += s;
                            let (mut truth, mut rival) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
                            for (&c, r) in self.alphabet.iter().zip(cell_scores) {
                                if c == cell.truth {
                                    truth = polarity * r;
                                } else {
                                    rival = rival.max(polarity * r);
                                }
                            }
                            margin = margin.min(truth - rival);
                        }
                        let confidence = total / self.cells.len() as f64;
                        if best.as_ref().is_none_or(|b| confidence > b.0) {
                            best = Some((confidence, read, margin));
                        }
                    }
                }
            }
        }
        let (confidence, read, margin) = best.expect("the unshifted reading always exists");
        let right = read.iter().zip(&self.cells).filter(|(r, c)| **r == c.truth).count() as u32;
        KnownFontRead {
            text: read.into_iter().collect(),
            correct: right as usize == self.cells.len(),
            characters_right: right,
            characters: self.cells.len() as u32,
            confidence,
            margin,
            chance: self.chance(),
        }
    }

    /// The correlation of each candidate of `cell` with the view's cell moved by (dx, dy) grid pixels; `None`
    /// when the moved cell leaves the grid.
    fn cell_scores(&self, cell: &Cell, view: &[f32], dx: isize, dy: isize) -> Option<Vec<f64>> {
        let (x0, y0) = (cell.x0 as isize + dx, cell.y0 as isize + dy);
        if x0 < 0 || y0 < 0 || x0 as usize + cell.w > self.width || y0 as usize + cell.h > self.height {
            return None;
        }
        let patch = crop(view, self.width, x0, y0, cell.w, cell.h);
        Some(cell.templates.iter().map(|t| ncc(&patch, t)).collect())
    }
}

/// The `w`×`h` box at (x0, y0) of a row-major image `width` wide (the box must lie inside it).
fn crop(img: &[f32], width: usize, x0: isize, y0: isize, w: usize, h: usize) -> Vec<f32> {
    let (x0, y0) = (x0 as usize, y0 as usize);
    (0..h)
        .flat_map(|y| img[(y0 + y) * width + x0..(y0 + y) * width + x0 + w].iter().copied())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn pin(digits: &str) -> (DocumentText, RgbImage) {
        let text = DocumentText {
            lines: vec!["PIN".into(), digits.into()],
            scale: 4,
            alphabet: "0123456789".into(),
        };
        let lines: Vec<&str> = text.lines.iter().map(String::as_str).collect();
        (text.clone(), glyphs::render_text(&lines, 128, 128, text.scale))
    }

    fn view_of(doc: &RgbImage, grid: u32) -> Vec<f32> {
        image_luminance(&imaging::resize(doc, grid, grid))
    }

    /// A view that is the document itself is read right, at both grid scales, and with a correlation of 1:
    /// the templates are the document's own glyphs resized the same way.
    #[test]
    fn reads_the_document_itself() {
        let (text, doc) = pin("4821");
        for grid in [64u32, 128] {
            let a = KnownFontAttacker::new(&text, 128, 128, grid, grid).unwrap();
            let r = a.read(&view_of(&doc, grid));
            assert_eq!(r.text, "4821");
            assert!(r.correct && r.characters_right == 4 && r.characters == 4);
            assert!((r.confidence - 1.0).abs() < 1e-6, "{}", r.confidence);
            assert!((r.chance - 1e-4).abs() < 1e-12);
            // Each cell is its true template, so the true glyph scores 1 and the margin is 1 minus the largest
            // correlation of a true template with another glyph's.
            let closest = a
                .cells
                .iter()
                .flat_map(|c| {
                    let t = a.alphabet.iter().position(|&x| x == c.truth).unwrap();
                    (0..c.templates.len())
                        .filter(move |&k| k != t)
                        .map(move |k| ncc(&c.templates[t], &c.templates[k]))
                })
                .fold(f64::NEG_INFINITY, f64::max);
            assert!(closest > 0.3 && closest < 0.95, "{closest}");
            assert!(
                (r.margin - (1.0 - closest)).abs() < 1e-6,
                "{} vs {}",
                r.margin,
                1.0 - closest
            );
        }
    }

    /// A different PIN in the same layout is read as that PIN, so the attack reads the view, not the truth;
    /// an inverted and faint view (the document at 5 % contrast, negative) is read too.
    #[test]
    fn reads_what_is_shown_in_either_polarity_and_at_low_contrast() {
        let (text, _) = pin("4821");
        let a = KnownFontAttacker::new(&text, 128, 128, 64, 64).unwrap();
        let (_, other) = pin("0736");
        let r = a.read(&view_of(&other, 64));
        assert_eq!(r.text, "0736");
        assert!(!r.correct && r.characters_right == 0);
        assert!(r.margin < 0.0, "a misread view has no margin: {}", r.margin);
        let (_, doc) = pin("4821");
        let faint: Vec<f32> = view_of(&doc, 64).iter().map(|v| 0.5 - 0.05 * v).collect();
        assert_eq!(a.read(&faint).text, "4821");
    }

    /// Views below the legibility threshold that the matched filter reads: the document under Gaussian noise of
    /// standard deviation 6.3 (its luminance contrast is 1) on a 128² grid scores legibility ≈ 0.21, under the
    /// threshold of 0.22, while a cell of ~860 pixels averages the noise down to ~6.3/√860 ≈ 0.21 of its
    /// correlation: the attacker reads some of 40 such views (1 with this seed), where guessing would read one
    /// in 10⁴. Pure noise is read right only at about chance: 0 of 200 noise views.
    #[test]
    fn reads_views_below_the_legibility_threshold_but_not_noise_alone() {
        let (text, doc) = pin("4821");
        let a = KnownFontAttacker::new(&text, 128, 128, 128, 128).unwrap();
        let clean = view_of(&doc, 128);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0f32, 6.3).unwrap();
        let (mut read, mut legibility) = (0, 0.0);
        for _ in 0..40 {
            let noisy: Vec<f32> = clean.iter().map(|v| v + normal.sample(&mut rng)).collect();
            legibility += crate::evaluation::legibility(&noisy, &clean, 128, 128) / 40.0;
            read += a.read(&noisy).correct as u32;
        }
        assert!(
            legibility < crate::evaluation::DEFAULT_THRESHOLD,
            "mean legibility {legibility}"
        );
        assert!(read >= 1, "read {read} of 40");
        let unit = Normal::new(0.0f32, 1.0).unwrap();
        let right = (0..200)
            .filter(|_| {
                let noise: Vec<f32> = clean.iter().map(|_| unit.sample(&mut rng)).collect();
                a.read(&noise).correct
            })
            .count();
        assert_eq!(right, 0);
    }

    /// A layout hint with the digits masked is resolved to the digits the document shows; a hint that names a
    /// different digit, or a layout that puts the digits elsewhere, is refused.
    #[test]
    fn a_masked_hint_is_resolved_from_the_document_and_a_wrong_one_refused() {
        let (text, doc) = pin("4821");
        let masked = DocumentText {
            lines: vec!["PIN".into(), "****".into()],
            ..text.clone()
        };
        assert_eq!(masked.resolve(&doc).unwrap(), text);
        let half = DocumentText {
            lines: vec!["PIN".into(), "4*2*".into()],
            ..text.clone()
        };
        assert_eq!(half.resolve(&doc).unwrap(), text);
        let wrong = DocumentText {
            lines: vec!["PIN".into(), "4*3*".into()],
            ..text.clone()
        };
        assert!(matches!(wrong.resolve(&doc), Err(KnownFontError::DoesNotMatch(m)) if m.contains("'3'")));
        let elsewhere = DocumentText {
            lines: vec!["****".into(), "PIN".into()],
            ..text.clone()
        };
        assert!(matches!(elsewhere.resolve(&doc), Err(KnownFontError::DoesNotMatch(_))));
        let too_many = DocumentText {
            lines: vec!["*".into(); 17],
            ..text
        };
        assert!(matches!(too_many.resolve(&doc), Err(KnownFontError::Layout(_))));
    }

    #[test]
    fn refuses_a_text_with_nothing_secret_or_a_bad_alphabet() {
        let (mut text, _) = pin("4821");
        text.alphabet = "XY".into();
        assert_eq!(
            KnownFontAttacker::new(&text, 128, 128, 64, 64).unwrap_err(),
            KnownFontError::NothingSecret
        );
        text.alphabet = "1".into();
        assert!(matches!(
            KnownFontAttacker::new(&text, 128, 128, 64, 64),
            Err(KnownFontError::Alphabet(_))
        ));
        text.alphabet = "01é".into();
        assert!(matches!(
            KnownFontAttacker::new(&text, 128, 128, 64, 64),
            Err(KnownFontError::Alphabet(_))
        ));
        text.alphabet = "0123456789".into();
        text.scale = 40;
        assert!(matches!(
            KnownFontAttacker::new(&text, 128, 128, 64, 64),
            Err(KnownFontError::OutsideDocument { .. })
        ));
    }
}
