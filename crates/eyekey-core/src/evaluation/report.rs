//! The report: scores of each view, summaries of the population, the camera attacker, the key and head movement; the evaluation's errors.

use crate::evaluation::{percentile, DEFAULT_THRESHOLD};
use image::RgbImage;
use serde::{Deserialize, Serialize};

/// Scores of one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ViewScore {
    /// Who or what looked.
    pub label: String,
    /// Contrast-invariant legibility (see [`legibility`]).
    pub legibility: f64,
    /// Plain NCC of the luminance with the document.
    pub ncc: f64,
    /// PSNR (dB) of the white-normalised luminance against the objective.
    pub psnr_db: f64,
    /// SSIM of the white-normalised luminance against the objective.
    pub ssim: f64,
    /// legibility ≥ threshold.
    pub readable: bool,
}

/// Summary of the population's readability.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PopulationSummary {
    /// People sampled.
    pub count: u32,
    /// How many could read.
    pub readable_count: u32,
    /// readable_count / count.
    pub readable_fraction: f64,
    /// Median legibility.
    pub median_legibility: f64,
    /// 95th-percentile legibility.
    pub p95_legibility: f64,
    /// Highest legibility.
    pub max_legibility: f64,
    /// Fraction of people at or above each of several legibility levels, as (level, fraction): a reader
    /// better than OCR (a person who knows the font) reads below the calibrated threshold.
    pub fraction_at_or_above: Vec<(f64, f64)>,
    /// Every person's score.
    pub people: Vec<ViewScore>,
}

impl PopulationSummary {
    /// The summary of every sampled person's score.
    pub fn from_scores(scores: Vec<ViewScore>) -> Self {
        let mut legs: Vec<f64> = scores.iter().map(|s| s.legibility).collect();
        legs.sort_by(|a, b| a.total_cmp(b));
        let readable = scores.iter().filter(|s| s.readable).count() as u32;
        let fraction = |t: f64| legs.iter().filter(|v| **v >= t).count() as f64 / legs.len().max(1) as f64;
        Self {
            count: scores.len() as u32,
            readable_count: readable,
            readable_fraction: readable as f64 / scores.len().max(1) as f64,
            median_legibility: percentile(&legs, 0.5),
            p95_legibility: percentile(&legs, 0.95),
            max_legibility: legs.last().copied().unwrap_or(0.0),
            fraction_at_or_above: [0.2, 0.3, DEFAULT_THRESHOLD, 0.5, 0.6]
                .iter()
                .map(|&t| (t, fraction(t)))
                .collect(),
            people: scores,
        }
    }
}

/// The camera attacker's best case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CameraSummary {
    /// The best configuration's score.
    pub best: ViewScore,
    /// Every configuration tried.
    pub tried: Vec<ViewScore>,
}

/// Legibility as a viewer's parameters move away from the target's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct KeySensitivity {
    /// Steps along each random direction in Zernike space (RMS µm over j = 3..=14).
    pub optical_steps_um: Vec<f64>,
    /// Legibility per direction per step.
    pub optical_legibility: Vec<Vec<f64>>,
    /// Median distance (µm) at which legibility first falls below threshold (the largest step if never).
    pub optical_radius_um: f64,
    /// Steps along random directions of the 8 Asano parameters, in population standard deviations.
    pub spectral_steps_sd: Vec<f64>,
    /// Legibility per direction per step.
    pub spectral_legibility: Vec<Vec<f64>>,
    /// Median distance (SDs) at which legibility falls below threshold.
    pub spectral_radius_sd: f64,
    /// Estimated distinguishable optical keys, bits: D_eff·log2(typical distance between people / radius).
    pub optical_bits: f64,
    /// Estimated distinguishable spectral keys, bits.
    pub spectral_bits: f64,
    /// Empirical lower bound from the population sample: −log2((readable + 1)/(count + 1)).
    pub empirical_bits: f64,
    /// How the estimates are made and what they ignore.
    pub method: String,
}

/// Legibility of the target as their eye moves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HeadMovement {
    /// Offsets tried (mm), each in four directions.
    pub offsets_mm: Vec<f64>,
    /// Worst legibility over the four directions, per offset.
    pub worst_legibility: Vec<f64>,
    /// Largest offset up to which every tried position still reads.
    pub readable_radius_mm: f64,
}

/// The whole evaluation report (`report.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Report {
    /// How legibility is measured.
    pub metric: String,
    /// Threshold used.
    pub threshold: f64,
    /// The target.
    pub target: ViewScore,
    /// Given observers.
    pub observers: Vec<ViewScore>,
    /// Sampled people.
    pub population: Option<PopulationSummary>,
    /// Camera attacker.
    pub camera: Option<CameraSummary>,
    /// Key sensitivity.
    pub key_sensitivity: Option<KeySensitivity>,
    /// Head movement.
    pub head_movement: Option<HeadMovement>,
}

/// A finished evaluation: the report and pictures (file name, image).
pub struct Evaluation {
    /// The report.
    pub report: Report,
    /// Pictures to save, e.g. ("target.png", …).
    pub pictures: Vec<(String, RgbImage)>,
}

/// Errors of an evaluation.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EvaluationError {
    /// Building an observer failed.
    #[error(transparent)]
    Observer(#[from] crate::physics::observer::ObserverError),
    /// The cancel flag was raised.
    #[error("cancelled")]
    Cancelled,
}
