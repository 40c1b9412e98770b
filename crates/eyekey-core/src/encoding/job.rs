//! A job: its inputs, what it produced, and why it failed.

use crate::physics::display::DisplayGeometry;
use crate::physics::profile::VisionProfile;
use std::path::PathBuf;

#[allow(unused_imports)]
use super::pipeline::*;

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
    pub manifest: serde_json::Value,
    /// The evaluation report as written to `report.json`.
    pub evaluation: serde_json::Value,
    /// Every file written into the output directory.
    pub files: Vec<PathBuf>,
}

/// Why a job did not produce a bundle.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// The inputs do not fit together (a client error; retrying will not help).
    #[error("invalid job: {0}")]
    Invalid(String),
    /// The cancel flag was raised.
    #[error("cancelled")]
    Cancelled,
    /// Anything else (I/O, numerical failure).
    #[error("{0}")]
    Internal(String),
}

/// Fraction of the display white the target is asked to see for document white: the rest is headroom the
/// encoder uses to show decoys to everybody else.
pub const OBJECTIVE_LEVEL: f64 = 0.5;

/// OSA terms whose ∂T/∂W_j the difference-maximisation encoder penalises: orders 2–3 (j = 3..=9), where the
/// population varies most (Indiana SDs of 0.1–0.37 µm at 6 mm).
pub const DIFFMAX_TERMS: std::ops::RangeInclusive<usize> = 3..=9;
