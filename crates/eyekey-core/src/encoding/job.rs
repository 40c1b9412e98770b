//! A job: its inputs, what it produced, and why it failed.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::options::EncodeOptions;
use super::solver::Termination;
use crate::bundle::Manifest;
use crate::evaluation::Report;
use crate::physics::display::DisplayGeometry;
use crate::physics::profile::VisionProfile;

/// Everything one job needs.
#[derive(Clone, Debug)]
pub struct JobSpec {
    /// The display the frames are for.
    pub display: DisplayGeometry,
    /// The person who must read the document.
    pub target: VisionProfile,
    /// Identifier of the target's profile and version, recorded in the manifest (never the profile itself).
    pub target_label: String,
    /// Representative observers, each shown the decoy.
    pub observers: Vec<VisionProfile>,
    /// The document (sRGB).
    pub document: image::RgbImage,
    /// Optional decoy image (sRGB), same aspect ratio as the document.
    pub decoy: Option<image::RgbImage>,
    /// Encoder options.
    pub options: EncodeOptions,
}

/// What a finished job produced.
#[derive(Clone, Debug)]
pub struct JobOutput {
    /// The bundle's manifest as written to `manifest.json`.
    pub manifest: Manifest,
    /// The evaluation report as written to `report.json` (none when the job was not evaluated).
    pub evaluation: Option<Report>,
    /// Every file written into the output directory.
    pub files: Vec<PathBuf>,
}

/// What a finished job produced, in memory: the bundle's manifest, the evaluation report, and every output
/// file as (path relative to the output directory, bytes): the bundle's files (`frame_<n>.png`,
/// `barrier_mask.png`, `manifest.json`) and the operator-only `encoding.json`, `report.json` and
/// `views/<name>.png`.
#[derive(Clone, Debug)]
pub struct RenderedJob {
    /// The bundle's manifest, as in `manifest.json`.
    pub manifest: Manifest,
    /// The evaluation report, as in `report.json` (none when the job was not evaluated).
    pub evaluation: Option<Report>,
    /// Every output file: relative path and contents.
    pub files: Vec<(String, Vec<u8>)>,
}

/// Name of the operator's record of an encode ([`EncodingRecord`]), written beside the bundle, never in it.
pub const ENCODING_FILE: &str = "encoding.json";

/// How an encode was made, for the operator who must audit or reproduce it: `encoding.json` beside the bundle
/// (sealed in the service, served at `/v1/jobs/{id}/encoding`). A display never receives it: it holds the seed,
/// and the seed is what makes the decoys' noise unknown to everybody else.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodingRecord {
    /// Identifier of the target's profile and version (never the profile itself).
    pub target_label: String,
    /// The encoder's options as run: defaults filled in and `seed` set to the one the encode drew from, so that
    /// encoding the same inputs with these options gives the same frames. Without the document's text.
    pub options: EncodeOptions,
    /// What the solver did.
    pub solver: SolverSummary,
}

/// What the solver did over all rounds of an encode; recorded in the operator's [`EncodingRecord`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolverSummary {
    /// The algorithm, in words.
    pub algorithm: String,
    /// Iterations over all rounds.
    pub iterations: u32,
    /// Momentum restarts over all rounds.
    pub restarts: u32,
    /// Why the last round stopped.
    pub termination: Termination,
    /// The objective at the end of the last round.
    pub objective: f64,
    /// The objective after every iteration of every round.
    pub objective_history: Vec<f64>,
    /// The last round's Lipschitz constant (step = 1/L).
    pub lipschitz: f64,
    /// Solver wall time over all rounds, seconds.
    pub seconds: f64,
    /// Observer terms in the final objective (target, head-box copies, decoys).
    pub observers: usize,
    /// Decoys added by each adaptive round.
    pub adaptive_decoys_added: Vec<usize>,
    /// What each head-box round (`head_rounds`) saw and added.
    #[serde(default)]
    pub head_rounds: Vec<HeadRound>,
    /// What each bystander camera round (`bystander_rounds`) saw and added.
    #[serde(default)]
    pub bystander_rounds: Vec<BystanderRound>,
    /// Unknowns of the light field.
    pub unknowns: usize,
    /// The factor the decoys' weights (noise and leak) were finally scaled by: 1 unless the target did not read
    /// its own view and `ensure_target_reads` halved them (and tried √2 back up) and solved again.
    pub decoy_weight_scale: f64,
    /// Whether the target reads its own view of the final light field, by the evaluation's judge (the known-font
    /// attacker with a text hint, the legibility threshold without), through the encoder's own operator and
    /// through one whose kernels are drawn with another seed, by the target's bar (every secret character read
    /// with the margin asked where the text is known; else legibility at least
    /// [`READS_THRESHOLD`](crate::evaluation::READS_THRESHOLD)).
    pub target_reads: bool,
    /// The final light field's reading by the target, through whichever of the two looks is further from reading:
    /// the judge, its score and the bar.
    #[serde(default)]
    pub target_reading: Option<crate::evaluation::TargetReading>,
    /// Every draw tried and what the encoder's own checks saw of it (`draws` > 1; empty otherwise). The rest of the
    /// summary (iterations, time, solves) is the kept draw's.
    #[serde(default)]
    pub draws: Vec<DrawCheck>,
    /// Every solve of the encode in order: the adaptive rounds', then the target guard's.
    #[serde(default)]
    pub solves: Vec<SolveStep>,
}

/// One draw of an encode with `draws` > 1 ([`SolverSummary::draws`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct DrawCheck {
    /// The draw's seed.
    pub seed: u64,
    /// Whether the target reads its own view at the seat.
    pub target_reads: bool,
    /// Head-ring positions (1–5 mm, four directions) a tracked target reads, of `ring_positions` (0 of 0 without a
    /// head ring).
    pub ring_read: u32,
    /// Head-ring positions looked at.
    pub ring_positions: u32,
    /// Fresh people at the seat who read, of `people`.
    pub people_read: u32,
    /// Fresh people looked at.
    pub people: u32,
    /// Camera settings and channels that read at the seat and at its first repeat 10 mm or more away, right,
    /// left, above and below (the evaluation's focus sweep through the check's own kernels), of `cameras`.
    #[serde(default)]
    pub cameras_read: u32,
    /// Camera settings and channels looked at.
    #[serde(default)]
    pub cameras: u32,
    /// Of `confirm_people` more fresh people at the seat, sampled as the evaluation samples them and looked at
    /// through a kernel draw of their own, those who read: the second look a draw gets when its check held the
    /// seat and it could be kept (0 of 0 otherwise).
    #[serde(default)]
    pub confirm_read: u32,
    /// People the confirmation looked at.
    #[serde(default)]
    pub confirm_people: u32,
    /// Whether this draw's light field was kept.
    pub kept: bool,
}

/// One head-box round ([`SolverSummary::head_rounds`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HeadRound {
    /// Ring positions the tracked target looked from.
    pub positions: u32,
    /// Of those, the positions where it read.
    pub read: u32,
    /// Eye positions (x, y, mm from the seat) whose tracked eye joined the target's stacked positions.
    pub added: Vec<[f64; 2]>,
    /// Stacked eye positions (x, y, mm) whose tracked eye still misread, their weight raised
    /// (`HEAD_ROUND_WEIGHT_STEP`), with the weight each now has.
    #[serde(default)]
    pub raised: Vec<RaisedPosition>,
}

/// A stacked head-box position whose weight a round raised ([`HeadRound::raised`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RaisedPosition {
    /// x, y, mm from the seat.
    pub at: [f64; 2],
    /// The position's weight from now on, against the design position's 1.
    pub weight: f64,
}

/// One bystander camera round ([`SolverSummary::bystander_rounds`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BystanderRound {
    /// Camera settings (position, lens and channel) looked through.
    pub settings: usize,
    /// Of those, the settings the judge read (as seen or unwarped).
    pub read: usize,
    /// The known-font attacker's best margin over every setting (negative: every setting misreads a character);
    /// absent without a text hint.
    pub best_margin: Option<f64>,
    /// Settings added as decoys.
    pub added: usize,
}

/// One solve of an encode ([`SolverSummary::solves`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveStep {
    /// The factor the decoys' weights were scaled by.
    pub decoy_weight_scale: f64,
    /// Its iterations.
    pub iterations: u32,
    /// Why it stopped: `stopped` where the target guard found the target reading its iterate clearly
    /// (`target_reads` true), or gave the solve up, the target's reading out of its reach (`target_reads` false).
    pub termination: Termination,
    /// Whether the target read its end, where it was judged (an adaptive round before the last is not).
    pub target_reads: Option<bool>,
}

/// Why a job did not produce a bundle.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// The inputs do not fit together (a client error; retrying will not help).
    #[error("invalid job: {field}: {reason}")]
    Invalid {
        /// The offending input, as a path: `options.sub_rays`, `document`, `observers[2]`.
        field: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The target does not read its frames, even with the decoys as light as the target guard takes them
    /// (`ensure_target_reads`): the job must not deliver frames its key holder cannot read.
    #[error(
        "{TARGET_CANNOT_READ}: the target does not read its view of the frames ({}), even with the decoys at \
         {decoy_weight_scale} of their weight; what would help: fewer or lighter decoys (population_decoys, \
         near_pupil_decoys, decoy_weight), a larger text scale, a display that resolves more views, or, where the \
         document is a rendered text, its text hint (document_text)",
        reading.evidence()
    )]
    TargetCannotRead {
        /// The final light field's reading by the target: judge, score and bar.
        reading: crate::evaluation::TargetReading,
        /// The factor the decoys' weights were scaled by at the end.
        decoy_weight_scale: f64,
    },
    /// The cancel flag was raised.
    #[error("cancelled")]
    Cancelled,
    /// Anything else (I/O, numerical failure).
    #[error("{context}{}", source.as_ref().map(|e| format!(": {e}")).unwrap_or_default())]
    Internal {
        /// What was being done.
        context: String,
        /// The underlying error, if any.
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
}

impl PipelineError {
    /// An [`PipelineError::Invalid`] for `field`.
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Invalid {
            field: field.into(),
            reason: reason.into(),
        }
    }

    /// An [`PipelineError::Internal`] while doing `context`, caused by `source`.
    pub fn internal(context: impl Into<String>, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self::Internal {
            context: context.into(),
            source: Some(Box::new(source)),
        }
    }
}

/// The code a job that fails because its target does not read ends with ([`PipelineError::TargetCannotRead`]).
pub const TARGET_CANNOT_READ: &str = "target_cannot_read";

/// Fraction of the display white the target is asked to see for document white: the rest is headroom the
/// encoder uses to show decoys to everybody else.
pub const OBJECTIVE_LEVEL: f64 = 0.5;

/// OSA terms whose ∂T/∂W_j the difference-maximisation encoder penalises: orders 2–3 (j = 3..=9), where the
/// population varies most (Indiana SDs of 0.1–0.37 µm at 6 mm).
pub const DIFFMAX_TERMS: std::ops::RangeInclusive<usize> = 3..=9;
