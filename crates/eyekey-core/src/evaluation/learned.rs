//! The learned reader: a judge trained on other jobs' frames (docs/design.md §4, docs/experiments.md §0b).
//!
//! An attacker who knows eyekey can encode PIN slips for sampled targets, simulate what people see of them, and
//! train a reader on the character cells; measured on fresh encodings, such a reader reads PINs the matched filter
//! misses. eyekey ships the linear one for the layouts it was trained on (`data/readers/`: eyekey's PIN slip on
//! `secure` and on `lenslet`, made by
//! `benches/learned_reader/train.py --export` on `eyekey experiment reader-views` output) and the evaluation counts
//! it: per secret cell, the digit of highest softmax(W·x + b), x the cell's luminance normalised to zero mean and
//! unit variance (so the view's contrast and the viewer's white do not matter). It applies only to a document
//! whose four secret digits land on exactly the cells, and the view on exactly the grid, it was trained on; for
//! every other document the report says no learned reader was applied.

use serde::{Deserialize, Serialize};

use crate::evaluation::KnownFontAttacker;

/// The readers eyekey ships, as trained (JSON).
const SHIPPED: &[&str] = &[
    include_str!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/readers/secure-pin-slip.json"
    )),
    include_str!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/readers/lenslet-pin-slip.json"
    )),
];

/// One cell's linear model over the ten digits.
#[derive(Clone, Debug, Deserialize)]
struct CellModel {
    /// W: ten rows of the cell's pixel count.
    weights: Vec<Vec<f32>>,
    /// b: ten.
    bias: Vec<f32>,
}

/// A linear reader for one layout of four digits on one retinal grid.
#[derive(Clone, Debug, Deserialize)]
pub struct LearnedReader {
    /// The display preset it was trained on.
    pub preset: String,
    /// The retinal grid, width × height.
    grid: [usize; 2],
    /// Each secret cell's box on the grid: x0, y0, width, height.
    cells: Vec<[usize; 4]>,
    /// How it was made.
    pub made: String,
    models: Vec<CellModel>,
}

/// What the learned reader made of one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct LearnedRead {
    /// The digits as read, in text order.
    pub text: String,
    /// Every digit right.
    pub correct: bool,
    /// How many digits are right.
    pub characters_right: u32,
}

/// A learned reader bound to one document: the reader and the digits it must find.
#[derive(Clone, Debug)]
pub struct BoundReader {
    reader: LearnedReader,
    truth: Vec<u8>,
}

impl LearnedReader {
    /// Parses a reader and checks its shapes.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let r: Self = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if r.cells.len() != r.models.len() || r.cells.is_empty() {
            return Err(format!("{} cells but {} models", r.cells.len(), r.models.len()));
        }
        for (c, m) in r.cells.iter().zip(&r.models) {
            let n = c[2] * c[3];
            if m.bias.len() != 10 || m.weights.len() != 10 || m.weights.iter().any(|w| w.len() != n) {
                return Err(format!(
                    "a cell of {n} pixels needs 10 rows of {n} weights and 10 biases"
                ));
            }
            if c[0] + c[2] > r.grid[0] || c[1] + c[3] > r.grid[1] {
                return Err(format!("cell {c:?} outside the {:?} grid", r.grid));
            }
        }
        Ok(r)
    }

    /// The readers eyekey ships, parsed once.
    pub fn shipped() -> &'static [Self] {
        static READERS: std::sync::OnceLock<Vec<LearnedReader>> = std::sync::OnceLock::new();
        READERS.get_or_init(|| {
            SHIPPED
                .iter()
                .map(|t| Self::from_json(t).expect("a shipped reader parses"))
                .collect()
        })
    }

    /// The shipped reader for the document the known-font `attacker` reads on a `grid`-sized retina, when one was
    /// trained on exactly its layout: digits only, the same secret cells on the same grid.
    pub fn for_document(attacker: &KnownFontAttacker, grid: (u32, u32)) -> Option<BoundReader> {
        let secret = attacker.secret();
        let digits_only = attacker.alphabet().iter().collect::<String>() == "0123456789";
        if !digits_only {
            return None;
        }
        Self::shipped().iter().find_map(|reader| {
            let fits = reader.grid == [grid.0 as usize, grid.1 as usize]
                && reader.cells.len() == secret.len()
                && reader
                    .cells
                    .iter()
                    .zip(&secret)
                    .all(|(c, (_, (x0, y0, w, h)))| *c == [*x0, *y0, *w, *h]);
            fits.then(|| BoundReader {
                reader: reader.clone(),
                truth: secret.iter().map(|(ch, _)| *ch as u8 - b'0').collect(),
            })
        })
    }

    /// The digit each cell of the luminance `view` (row-major on the grid) most probably shows.
    pub fn read_digits(&self, view: &[f32]) -> Vec<u8> {
        assert_eq!(view.len(), self.grid[0] * self.grid[1], "view size");
        self.cells
            .iter()
            .zip(&self.models)
            .map(|(&[x0, y0, w, h], m)| {
                let mut x: Vec<f64> = (y0..y0 + h)
                    .flat_map(|y| (x0..x0 + w).map(move |xx| (y, xx)))
                    .map(|(y, xx)| view[y * self.grid[0] + xx] as f64)
                    .collect();
                let mean = x.iter().sum::<f64>() / x.len() as f64;
                let sd = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / x.len() as f64).sqrt();
                for v in &mut x {
                    *v = (*v - mean) / sd.max(1e-9);
                }
                let logit =
                    |d: usize| m.bias[d] as f64 + m.weights[d].iter().zip(&x).map(|(w, v)| *w as f64 * v).sum::<f64>();
                (0..10).max_by(|a, b| logit(*a).total_cmp(&logit(*b))).unwrap_or(0) as u8
            })
            .collect()
    }
}

impl BoundReader {
    /// The reader applied to the luminance `view`.
    pub fn read(&self, view: &[f32]) -> LearnedRead {
        let digits = self.reader.read_digits(view);
        let right = digits.iter().zip(&self.truth).filter(|(a, b)| a == b).count() as u32;
        LearnedRead {
            text: digits.iter().map(|d| char::from(b'0' + d)).collect(),
            correct: right as usize == self.truth.len(),
            characters_right: right,
        }
    }

    /// How the reader was made.
    pub fn made(&self) -> &str {
        &self.reader.made
    }

    /// What gives each cell's true digit its lead in the reader's arg-max: per cell, its box on the grid (x0, y0,
    /// width, height) and, for each other digit d, W_true − W_d (row-major in the box). A crop orthogonal to all
    /// nine, after the reader's mean removal, leaves the true digit no lead but its bias.
    pub fn discriminants(&self) -> Vec<(crate::evaluation::CellBox, Vec<f32>)> {
        let mut out = Vec::new();
        for ((&[x0, y0, w, h], m), &t) in self.reader.cells.iter().zip(&self.reader.models).zip(&self.truth) {
            let t = t as usize;
            for d in (0..10).filter(|&d| d != t) {
                let q = m.weights[t].iter().zip(&m.weights[d]).map(|(a, b)| a - b).collect();
                out.push(((x0, y0, w, h), q));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::DocumentText;

    /// eyekey's PIN slip for a display whose retinal grid is `grid` (the document 4 pixels a grid pixel, as
    /// `eyekey experiment reader-views` draws it).
    fn slip(grid: [usize; 2], pin: &str) -> (image::RgbImage, DocumentText, KnownFontAttacker) {
        let (w, h) = (grid[0] as u32 * 4, grid[1] as u32 * 4);
        let text = DocumentText {
            lines: vec!["PIN".into(), pin.into()],
            scale: w / 28,
            alphabet: "0123456789".into(),
        };
        let doc = crate::imaging::glyphs::render_text(&["PIN", pin], w, h, text.scale);
        let attacker = KnownFontAttacker::new(&text, w, h, grid[0] as u32, grid[1] as u32).unwrap();
        (doc, text, attacker)
    }

    #[test]
    fn a_reader_ships_for_the_secure_and_lenslet_pin_slips_and_each_applies_to_its_own_layout_only() {
        let shipped = LearnedReader::shipped();
        let presets: Vec<&str> = shipped.iter().map(|r| r.preset.as_str()).collect();
        assert_eq!(presets, ["secure", "lenslet"]);
        for reader in shipped {
            let [gw, gh] = reader.grid;
            let (_, text, attacker) = slip(reader.grid, "4821");
            let bound = LearnedReader::for_document(&attacker, (gw as u32, gh as u32)).expect("its own layout");
            assert_eq!(bound.made(), reader.made);
            // Another grid, or the slip drawn at another scale, is not the layout it learned.
            assert!(LearnedReader::for_document(&attacker, (gw as u32 + 8, gh as u32)).is_none());
            let (w, h) = (gw as u32 * 4, gh as u32 * 4);
            let small = DocumentText {
                scale: text.scale - 1,
                ..text.clone()
            };
            let other = KnownFontAttacker::new(&small, w, h, gw as u32, gh as u32).unwrap();
            assert!(LearnedReader::for_document(&other, (gw as u32, gh as u32)).is_none());
            // Letters in the alphabet: not the digits it knows.
            let letters = DocumentText {
                alphabet: "0123456789AB".into(),
                ..text
            };
            let other = KnownFontAttacker::new(&letters, w, h, gw as u32, gh as u32).unwrap();
            assert!(LearnedReader::for_document(&other, (gw as u32, gh as u32)).is_none());
        }
        // The two grids differ, so no slip binds the other display's reader.
        assert_ne!(shipped[0].grid, shipped[1].grid);
    }

    #[test]
    fn each_shipped_reader_reads_the_plain_slip_far_above_chance_and_secure_s_reads_it_whole() {
        // The plain document on the grid is what a perfect eye on a plain display sees: cleaner than any view a
        // reader was trained on, so it tests the wiring (cells, order, normalisation), not the reader's skill.
        // Ten slips put every digit in every cell once. Chance is 4 of 40 digits, and a cell box or a
        // transposition wrong reads about that; `secure`'s reader reads all 40, `lenslet`'s (trained on fewer
        // encodings of larger cells) 36, a clean 6 taken for a 3 among them.
        for reader in LearnedReader::shipped() {
            let [gw, gh] = reader.grid;
            let mut right = 0;
            for first in 0..10u8 {
                let pin: String = (0..4).map(|k| char::from(b'0' + (first + k) % 10)).collect();
                let (doc, _, attacker) = slip(reader.grid, &pin);
                let bound = LearnedReader::for_document(&attacker, (gw as u32, gh as u32)).unwrap();
                let view = crate::evaluation::image_luminance(&crate::imaging::resize(&doc, gw as u32, gh as u32));
                let read = bound.read(&view);
                right += read.characters_right;
                if reader.preset == "secure" {
                    assert!(read.correct, "{pin}: {read:?}");
                }
            }
            assert!(right >= 30, "{}: {right} of 40 digits", reader.preset);
        }
    }

    #[test]
    fn a_reader_whose_weights_do_not_fit_its_cells_is_refused() {
        let one = |n: usize| {
            serde_json::json!({
                "preset": "x", "grid": [8, 8], "cells": [[0, 0, 2, 2]], "made": "",
                "models": [{"weights": vec![vec![0.0; n]; 10], "bias": vec![0.0; 10]}]
            })
            .to_string()
        };
        assert!(LearnedReader::from_json(&one(4)).is_ok());
        assert!(LearnedReader::from_json(&one(5)).is_err());
    }
}
