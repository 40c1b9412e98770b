//! What an evaluation looks at, and how hard.

use crate::evaluation::DEFAULT_THRESHOLD;
use crate::physics::accommodation::Accommodation;
use crate::physics::observer::Optics;
use serde::{Deserialize, Serialize};

/// Options of an evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default)]
pub struct EvaluationOptions {
    /// The forward model every simulated view uses.
    pub optics: Optics,
    /// People sampled from the population statistics.
    pub population: u32,
    /// Seed of the population sample (different from the encoder's decoys by construction).
    pub seed: u64,
    /// Legibility threshold.
    pub threshold: f64,
    /// Sub-rays per sample in the evaluation's transport (its own jitter seed).
    pub sub_rays: u32,
    /// Camera focus errors swept, dioptres.
    pub camera_focus_d: Vec<f64>,
    /// Camera apertures tried, mm.
    pub camera_apertures_mm: Vec<f64>,
    /// Random directions for the key-sensitivity scan (0 skips it).
    pub key_directions: u32,
    /// Eye offsets (mm) for the head-movement scan (empty skips it).
    pub head_offsets_mm: Vec<f64>,
    /// Population views saved as pictures.
    pub saved_population_views: u32,
    /// The document's text, font and secret alphabet, when known (a PIN slip eyekey rendered): every view is
    /// then also read by the known-font attacker.
    pub document_text: Option<crate::evaluation::DocumentText>,
    /// Bystanders anywhere else (people and a focus-sweeping camera on a grid of positions); None skips them.
    pub bystanders: Option<crate::evaluation::BystanderOptions>,
    /// Where the text is known, the known-font margin the target must read its view with to be called read
    /// (the job's `target_margin`).
    pub target_margin: f64,
    /// The focus range every sampled person, bystander and named observer is judged over: each reads when any
    /// focus in it reads ([`Accommodation::fixed`] holds everyone at their profile's focus).
    pub accommodation: Accommodation,
}

impl EvaluationOptions {
    /// The seed of the evaluation's kernel draws (its own jitter seed, apart from the encoder's).
    pub fn transport_seed(&self) -> u64 {
        self.seed ^ 0xE7A1
    }

    /// Only `population` people at the target's position (with the document's text, when known): no camera, key
    /// sensitivity or head movement; the other options at their defaults.
    pub fn population_only(population: u32, document_text: Option<crate::evaluation::DocumentText>) -> Self {
        Self {
            population,
            document_text,
            key_directions: 0,
            head_offsets_mm: vec![],
            camera_focus_d: vec![],
            ..Default::default()
        }
    }
}

impl Default for EvaluationOptions {
    fn default() -> Self {
        Self {
            optics: Optics::Wave,
            population: 20,
            seed: 20_000,
            threshold: DEFAULT_THRESHOLD,
            sub_rays: 16,
            camera_focus_d: vec![-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0],
            camera_apertures_mm: vec![2.0, 4.0, 6.0],
            key_directions: 3,
            head_offsets_mm: vec![0.5, 1.0, 2.0, 4.0],
            saved_population_views: 3,
            document_text: None,
            bystanders: None,
            target_margin: 0.0,
            accommodation: Accommodation::default(),
        }
    }
}
