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
    /// What the known-font attacker read, when the document's text is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known_font: Option<crate::evaluation::KnownFontRead>,
    /// What the learned reader read, when one was trained on the document's layout
    /// ([`LearnedReader`](crate::evaluation::LearnedReader)).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learned: Option<crate::evaluation::LearnedRead>,
    /// For a viewer who may refocus: the accommodation this view was seen at, dioptres of power added to the
    /// profile's eye (+ nearer, 0 its own focus; `EvaluationOptions::accommodation`): the first focus that reads,
    /// else the most legible.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus_d: Option<f64>,
    /// The known-font attacker (or the learned reader) read every secret character (when the document's text is
    /// known); otherwise legibility ≥ threshold: somebody *might* read it. For the report's target, whether the target *reads* it,
    /// by the target's stricter bar ([`Report::target_reading`]).
    pub readable: bool,
}

/// Which judge decided whether the target reads ([`TargetReading`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum TargetJudge {
    /// The known-font attacker (the document's text, font and layout are known): every secret character read
    /// right, with the true glyph's lead over the best other at least the margin asked.
    KnownFont,
    /// Legibility (nothing known of the text): at least [`READS_THRESHOLD`](crate::evaluation::READS_THRESHOLD),
    /// the level at which the known-font attacker reads 99 % of calibration views.
    Legibility,
    /// No judge is right on this document: nothing is known of its text, and its characters land on the retina
    /// smaller than any the legibility judge was calibrated on
    /// ([`MIN_JUDGED_TEXT_PX`](crate::evaluation::MIN_JUDGED_TEXT_PX)); `score` is their height in pixels, and the
    /// target is never said to read.
    Unknown,
}

/// Whether the target reads its view, which judge decided, and by how much.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct TargetReading {
    /// The judge.
    pub judge: TargetJudge,
    /// Whether the target reads: every secret character right and `score` ≥ `bar`.
    pub reads: bool,
    /// What the judge measured: the known-font margin (the true glyph's smallest lead, negative when a character
    /// is misread) or the legibility.
    pub score: f64,
    /// The bar `score` must reach: the margin asked (`target_margin`) or the reads threshold.
    pub bar: f64,
}

impl TargetReading {
    /// `score` − `bar`: how far the view is past the bar (negative: short of it).
    pub fn margin(&self) -> f64 {
        self.score - self.bar
    }

    /// The verdict with its evidence, for people: "reads it (known-font attacker: margin 0.112, asked 0.000)".
    pub fn describe(&self) -> String {
        let verdict = match (self.judge, self.reads) {
            (TargetJudge::Unknown, _) => "may or may not read it",
            (_, true) => "reads it",
            (_, false) => "does not read it",
        };
        format!("{verdict} ({})", self.evidence())
    }

    /// What the judge measured against what it asked: "known-font attacker: margin 0.112, asked 0.000", or "no
    /// text hint: legibility 0.31, read from 0.70".
    pub fn evidence(&self) -> String {
        match self.judge {
            TargetJudge::KnownFont => format!("known-font attacker: margin {:.3}, asked {:.3}", self.score, self.bar),
            TargetJudge::Legibility => format!("no text hint: legibility {:.2}, read from {:.2}", self.score, self.bar),
            TargetJudge::Unknown => format!(
                "unknown: no text hint, and characters {:.1} px tall on the retina, below the {:.0} px the judge is \
                 calibrated from",
                self.score, self.bar
            ),
        }
    }
}

/// Summary of the population's readability.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PopulationSummary {
    /// People sampled.
    pub count: u32,
    /// How many could read.
    pub readable_count: u32,
    /// How many of them read at their own focus (without refocusing).
    #[serde(default)]
    pub readable_at_own_focus: u32,
    /// readable_count / count.
    pub readable_fraction: f64,
    /// 95 % confidence interval of the fraction who read (Wilson score interval).
    pub readable_ci95: (f64, f64),
    /// How many the known-font attacker read (when the document's text is known).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known_font_readers: Option<u32>,
    /// How many the learned reader read (when one was trained on the document's layout).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learned_readers: Option<u32>,
    /// How many the known-font attacker read with at most one secret character wrong: the readers of an
    /// attacker allowed one guess per candidate of the character it is least sure of (10 guesses for a PIN).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known_font_all_but_one: Option<u32>,
    /// Median legibility.
    pub median_legibility: f64,
    /// 95th-percentile legibility.
    pub p95_legibility: f64,
    /// Highest legibility.
    pub max_legibility: f64,
    /// Fraction of people at or above each of several legibility levels, as (level, fraction): the continuous
    /// figure beside the judge's count (the calibrated threshold is among the levels).
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
        let readable_at_own_focus = scores
            .iter()
            .filter(|s| s.readable && s.focus_d.unwrap_or(0.0) == 0.0)
            .count() as u32;
        let fraction = |t: f64| legs.iter().filter(|v| **v >= t).count() as f64 / legs.len().max(1) as f64;
        let known_font_readers = scores.iter().any(|s| s.known_font.is_some()).then(|| {
            scores
                .iter()
                .filter(|s| s.known_font.as_ref().is_some_and(|k| k.correct))
                .count() as u32
        });
        let learned_readers = scores.iter().any(|s| s.learned.is_some()).then(|| {
            scores
                .iter()
                .filter(|s| s.learned.as_ref().is_some_and(|k| k.correct))
                .count() as u32
        });
        let known_font_all_but_one = known_font_readers.map(|_| {
            scores
                .iter()
                .filter(|s| {
                    s.known_font
                        .as_ref()
                        .is_some_and(|k| k.characters_right + 1 >= k.characters)
                })
                .count() as u32
        });
        Self {
            count: scores.len() as u32,
            readable_count: readable,
            readable_at_own_focus,
            known_font_all_but_one,
            readable_fraction: readable as f64 / scores.len().max(1) as f64,
            readable_ci95: wilson_interval(readable as u64, scores.len() as u64, 1.959_964),
            known_font_readers,
            learned_readers,
            median_legibility: percentile(&legs, 0.5),
            p95_legibility: percentile(&legs, 0.95),
            max_legibility: legs.last().copied().unwrap_or(0.0),
            fraction_at_or_above: {
                let mut levels = vec![0.2, 0.3, DEFAULT_THRESHOLD, 0.5, 0.6];
                levels.sort_by(f64::total_cmp);
                levels.dedup();
                levels.iter().map(|&t| (t, fraction(t))).collect()
            },
            people: scores,
        }
    }
}

/// The Wilson score interval of a binomial proportion k/n at z standard deviations (Wilson 1927; Brown,
/// Cai & DasGupta 2001 recommend it over the normal approximation for small k): (p̂ + z²/2n ± z√(p̂(1−p̂)/n +
/// z²/4n²)) / (1 + z²/n). (0, 1) when n = 0.
pub fn wilson_interval(k: u64, n: u64, z: f64) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let (nf, p) = (n as f64, k as f64 / n as f64);
    let z2 = z * z;
    let centre = p + z2 / (2.0 * nf);
    let half = z * (p * (1.0 - p) / nf + z2 / (4.0 * nf * nf)).sqrt();
    let d = 1.0 + z2 / nf;
    (((centre - half) / d).max(0.0), ((centre + half) / d).min(1.0))
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
    /// Whether the target reads its view, by the target's bar: which judge decided and its margin.
    pub target_reading: TargetReading,
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
    /// Bystanders beside, above, nearer and farther, people and cameras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bystanders: Option<crate::evaluation::BystanderSummary>,
    /// How the learned reader that judged every view was made, when one was trained on the document's layout;
    /// absent, no learned reader was applied and only the known-font attacker (or legibility) judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learned_reader: Option<String>,
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
    /// The document's text hint does not fit the document.
    #[error("document text: {0}")]
    DocumentText(#[from] crate::evaluation::KnownFontError),
    /// The bystander options are out of range.
    #[error("bystanders: {0}")]
    Bystanders(String),
    /// The cancel flag was raised.
    #[error("cancelled")]
    Cancelled,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against values computed by hand from the formula (and tabulated by Brown, Cai & DasGupta 2001 for
    /// 5 of 10): 0 of 1000 → (0, 0.00383); 5 of 10 → (0.2366, 0.7634); 147 of 1000 → (0.1264, 0.1703).
    #[test]
    fn wilson_intervals_match_hand_values() {
        let close = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 5e-5 && (a.1 - b.1).abs() < 5e-5;
        let z = 1.959_964;
        assert!(
            close(wilson_interval(0, 1000, z), (0.0, 0.003_827)),
            "{:?}",
            wilson_interval(0, 1000, z)
        );
        assert!(
            close(wilson_interval(5, 10, z), (0.236_6, 0.763_4)),
            "{:?}",
            wilson_interval(5, 10, z)
        );
        assert!(
            close(wilson_interval(147, 1000, z), (0.126_4, 0.170_3)),
            "{:?}",
            wilson_interval(147, 1000, z)
        );
        assert_eq!(wilson_interval(0, 0, z), (0.0, 1.0));
    }

    #[test]
    fn the_known_font_counts_tell_whole_reads_from_reads_one_character_off() {
        let person = |right: u32| ViewScore {
            label: format!("{right} right"),
            legibility: 0.1 * right as f64,
            ncc: 0.0,
            psnr_db: 0.0,
            ssim: 0.0,
            focus_d: None,
            learned: None,
            known_font: Some(crate::evaluation::KnownFontRead {
                text: String::new(),
                correct: right == 4,
                characters_right: right,
                characters: 4,
                confidence: 0.5,
                margin: if right == 4 { 0.1 } else { -0.1 },
                chance: 1e-4,
            }),
            readable: right == 4,
        };
        let p = PopulationSummary::from_scores([4, 3, 3, 2, 0].map(person).to_vec());
        assert_eq!(
            (p.readable_count, p.known_font_readers, p.known_font_all_but_one),
            (1, Some(1), Some(3))
        );
        let mut plain = person(4);
        plain.known_font = None;
        let p = PopulationSummary::from_scores(vec![plain]);
        assert_eq!((p.known_font_readers, p.known_font_all_but_one), (None, None));
    }

    #[test]
    fn people_who_read_only_after_refocusing_count_as_readers_but_not_at_their_own_focus() {
        let person = |readable: bool, focus_d: Option<f64>| ViewScore {
            label: String::new(),
            legibility: 0.5,
            ncc: 0.0,
            psnr_db: 0.0,
            ssim: 0.0,
            focus_d,
            learned: None,
            known_font: None,
            readable,
        };
        let p = PopulationSummary::from_scores(vec![
            person(true, Some(0.0)),
            person(true, Some(0.75)),
            person(true, None),
            person(false, Some(-1.0)),
            person(false, Some(0.0)),
        ]);
        assert_eq!((p.readable_count, p.readable_at_own_focus), (3, 2));
    }
}
