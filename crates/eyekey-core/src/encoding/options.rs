//! What an encode is asked to do: the encoder, its decoys and ablations, and the solver's limits.

use crate::physics::display::DisplayGeometry;
use crate::physics::observer::Optics;
use serde::{Deserialize, Serialize};

use super::job::PipelineError;

/// Which encoder to run (paper §6).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Multiplex image display (Eq. 14), generalised to K weighted observers.
    #[default]
    Multiplex,
    /// Difference maximisation (Eq. 16).
    Diffmax,
    /// Multiplex objective plus the difference-maximisation terms.
    Combined,
}

/// Restrict the encoder to one kind of key (paper Figs. 14–15).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Ablation {
    /// Every observer is given the target's spectral coupling, and difference maximisation drops its λ_c
    /// term: only the optics differ.
    Optical,
    /// All views of a hole are forced equal (a plain multiband 2D display), and difference maximisation drops
    /// its λ_W term.
    Spectral,
}

/// What the decoy observers are shown.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum DecoyKind {
    /// A high-contrast random mask, a different one per decoy observer.
    #[default]
    Noise,
    /// Uniform mid grey.
    Grey,
    /// The decoy image supplied with the job (noise where none is given).
    Image,
}

/// How hard an encode hides the document, and what it asks of the target's eye in exchange: the one choice an
/// operator makes (`security`). Each level sets the target's states (the focus and pupil changes it must read
/// through) where `target_focus_d` and `target_pupil_mm` are left empty; the figures each level reaches on every
/// display are measured in docs/experiments.md §0.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Security {
    /// The target reads while its eye does what eyes do as they look: its focus drifts by ±0.25 D and its pupil
    /// by ±0.5 mm ([`STANDARD_FOCUS_STATES_D`], [`STANDARD_PUPIL_STATES_MM`], each a stacked target term the
    /// guard also judges). More of the people at the seat read than under `strict`.
    #[default]
    Standard,
    /// The target must hold its profile's focus and pupil (no stacked states): the fewest people at the seat
    /// read, and a target whose accommodation drifts by 0.25 D misreads.
    Strict,
}

/// The focus states `security: standard` stacks (dioptres added to the profile's sphere): accommodation's
/// ordinary drift while one looks at a near display.
pub const STANDARD_FOCUS_STATES_D: [f64; 2] = [-0.25, 0.25];

/// The pupil states `security: standard` stacks (mm added to the viewing pupil, within the measured one).
pub const STANDARD_PUPIL_STATES_MM: [f64; 2] = [-0.5, 0.5];

/// Options of one encode; every field has a sensible default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct EncodeOptions {
    /// How hard to hide, at what cost to the target's comfort ([`Security`]): the target states asked of it
    /// where `target_focus_d` and `target_pupil_mm` are empty.
    pub security: Security,
    /// The encoder.
    pub method: Method,
    /// The forward model the encoder (and the job's evaluation) uses: `wave` (diffraction at the apertures,
    /// the eye's chromatic defocus; docs/design.md §2.7) or `geometric` (the paper's straight rays).
    pub optics: Optics,
    /// Optional ablation.
    pub ablation: Option<Ablation>,
    /// Decoy observers sampled from the population, each shown a decoy (0 = only the given observers).
    #[cfg_attr(feature = "openapi", schema(maximum = 64))]
    pub population_decoys: u32,
    /// Population decoys look through the target's pupil: a sampled person whose pupil is larger than the
    /// target's is given the target's (their wavefront rescaled to it, ANSI Z80.28 Annex B), so the decoys
    /// compete for exactly the views the target sees.
    pub decoys_at_target_pupil: bool,
    /// At which focus the population and near-pupil decoys (and the adaptive rounds' candidates) look.
    pub decoy_focus: DecoyFocus,
    /// Further decoys whose pupils bracket the target's, evenly from 0.3 mm narrower to 0.7 mm wider (sampled
    /// people of at least that pupil, their wavefronts rescaled to it, ANSI Z80.28 Annex B). The people who read
    /// a small-pupil target's frames are those whose pupils are near its own: with 6 of them beside the 6
    /// population decoys, 2 of 600 held-out people read six held-out targets' frames, against 62 of 600 without
    /// (docs/experiments.md §2e).
    #[cfg_attr(feature = "openapi", schema(maximum = 16))]
    pub near_pupil_decoys: u32,
    /// When above 0 (mm): each near-pupil decoy is looked at once more, off the target's position on a ring of
    /// this radius (decoy k of n at angle 2πk/n), so that the eyes beside the seat (and a bystander just off one
    /// of the display's repeats, who sees what an eye beside the seat sees) are held to noise too. For frames
    /// whose target is stacked on a ring (`head_radius_mm`), which widens the seat (docs/experiments.md §2c).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 20.0))]
    pub near_pupil_ring_mm: f64,
    /// What decoy observers see.
    pub decoy: DecoyKind,
    /// Weight of each decoy observer's term relative to the target's (1.0). Absent, the display's default: 0.5
    /// on the `secure` design, 0.3 on every other; a job states the weight it was solved with in its options.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 100.0))]
    pub decoy_weight: Option<f64>,
    /// Weight of the leak penalty on every decoy (docs/design.md §3, "Leak penalty"): the squared projections of
    /// the decoy's view onto the document's ink-box pattern (plain and blurred) and, with `document_text`, onto
    /// each secret character's glyph discriminant at ±1 px, relative to the target's term (0 = off). With
    /// `decoy_weight` 0 the decoys are asked only not to see the document, not to see noise.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 100.0))]
    pub leak_weight: f64,
    /// With `document_text`, the leak penalty also covers each secret character's glyph discriminants (false: the
    /// ink-box patterns alone, as without a text hint, while the guard and the bystander rounds still judge by the
    /// known-font attacker).
    pub leak_glyphs: bool,
    /// With `leak_glyphs`, the leak penalty also covers the lead directions of the learned reader shipped for the
    /// document's layout, where there is one ([`LearnedReader`](crate::evaluation::LearnedReader)). Off by
    /// default: the evaluation judges with that same reader, and frames fitted against it evade it (on `secure`,
    /// 4 % of the people at the seat read against 19.7 %) without showing that a reader retrained on such frames
    /// would fail too (docs/experiments.md §0).
    pub leak_learned_reader: bool,
    /// The seed of every random choice of the encode: the population decoys, their noise masks, the draws, the
    /// kernels' sub-rays and the checks' people. Absent (the default), a seed is drawn for this encode from the
    /// operating system's CSPRNG ([`EncodeOptions::with_fresh_seed`]), so no two jobs share their decoys' noise
    /// and nobody can learn it from other jobs' frames (docs/design.md §5, "Fresh randomness"). Give one only to
    /// reproduce a job or for experiments: a seed anybody knows is a fixed pattern an attacker can learn and
    /// subtract. The service draws it when the job is created and keeps it sealed with the job; a display client
    /// never receives it.
    pub seed: Option<u64>,
    /// Sub-rays traced per light-field sample (S).
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 256))]
    pub sub_rays: u32,
    /// Solver iteration cap.
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 20000))]
    pub max_iterations: u32,
    /// Relative objective change below which the solver stops.
    #[cfg_attr(feature = "openapi", schema(exclusive_minimum = 0.0, exclusive_maximum = 1.0))]
    pub tolerance: f64,
    /// λ_W of Eq. 16 (difference maximisation), relative to the data term.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 100.0))]
    pub lambda_w: f64,
    /// λ_c of Eq. 16 (difference maximisation), relative to the data term.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 100.0))]
    pub lambda_c: f64,
    /// People sampled from the population for the evaluation report (0 skips it).
    #[cfg_attr(feature = "openapi", schema(maximum = 2000))]
    pub evaluation_population: u32,
    /// Head-movement robustness: besides the design position, the target must also read from four eye
    /// positions this far off axis (mm; 0 = only the design position). Stacked observers, as in the
    /// 2014 eyeglasses-free display.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 20.0))]
    pub head_radius_mm: f64,
    /// Eye positions on the head-movement ring, evenly spaced from the right (4 = right, left, up, down).
    #[cfg_attr(feature = "openapi", schema(minimum = 3, maximum = 16))]
    pub head_positions: u32,
    /// The weight of each head-movement position's term, relative to the design position's 1.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 4.0))]
    pub head_weight: f64,
    /// Adaptive decoy rounds: after each solve, sample `adaptive_candidates` fresh people and add up to
    /// `adaptive_per_round` of those who can still read as decoys, then solve again (0 = off).
    #[cfg_attr(feature = "openapi", schema(maximum = 5))]
    pub adaptive_rounds: u32,
    /// People sampled per adaptive round; with near-pupil decoys, half of them given pupils bracketing the
    /// target's.
    #[cfg_attr(feature = "openapi", schema(maximum = 200))]
    pub adaptive_candidates: u32,
    /// Decoys added per adaptive round at most.
    #[cfg_attr(feature = "openapi", schema(maximum = 16))]
    pub adaptive_per_round: u32,
    /// Camera decoys: an ideal lens of `camera_decoy_aperture_mm` focused at each of `camera_decoy_focus_d`
    /// behind a filter passing one projector band (the evaluation's strongest attacker), each shown a noise mask
    /// (and held to the leak penalty).
    pub camera_decoys: bool,
    /// Focus settings of the camera decoys, dioptres off the display (at most 9, each within ±5 D).
    #[cfg_attr(feature = "openapi", schema(max_items = 9))]
    pub camera_decoy_focus_d: Vec<f64>,
    /// Aperture of the camera decoys' lens, mm (2–10).
    #[cfg_attr(feature = "openapi", schema(minimum = 2.0, maximum = 10.0))]
    pub camera_decoy_aperture_mm: f64,
    /// Further apertures of the camera decoys' lens, mm (at most 3, each 2–10): each at every focus setting and
    /// position, beside `camera_decoy_aperture_mm`. Decoys behind one aperture hold the cameras of that aperture
    /// and leave others reading (docs/experiments.md §2c).
    #[cfg_attr(feature = "openapi", schema(max_items = 3))]
    pub camera_decoy_extra_apertures_mm: Vec<f64>,
    /// When above 0 (mm): the camera decoys are looked at once more from each of four positions on a ring of
    /// this radius around the target's (right, left, above, below). For frames whose target is stacked on a
    /// ring (`head_radius_mm`): a camera just beside the seat, and at the display's repeats a bystander who sees
    /// what it sees, reads those frames (docs/experiments.md §2c).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 20.0))]
    pub camera_decoy_ring_mm: f64,
    /// Head-box rounds (0 = off), for a display that re-indexes the frames for the tracked eye
    /// ([`retarget`](crate::physics::tracking::retarget)); wave optics only. After each solve, the target, its
    /// frames re-indexed, looks from rings of 1–5 mm around the seat (right, left, above, below; 20 positions)
    /// through a kernel draw of its own; up to [`HEAD_ROUND_MAX_ADDED`] positions where it does not read (the
    /// evaluation's judge, with `target_margin`), the most misread first, join the target's stacked positions as
    /// the tracked eye there (the operator T·R, `TransportOptions::tracked`; weight `head_weight`); a stacked
    /// position where it still misreads has its weight multiplied by [`HEAD_ROUND_WEIGHT_STEP`] (up to
    /// `head_round_max_weight`); and the solve runs again from its end.
    #[cfg_attr(feature = "openapi", schema(maximum = 3))]
    pub head_rounds: u32,
    /// The weight a head-box round raises a stacked position to at most (`head_weight` if that is larger),
    /// relative to the design position's 1: the design position's own by default ([`HEAD_ROUND_MAX_WEIGHT`]).
    /// Lower, the stacked positions ask less of the frames against the decoys at the seat (docs/experiments.md
    /// §2c).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 4.0))]
    pub head_round_max_weight: f64,
    /// Focus states the target must read in too, dioptres added to its profile's sphere (an eye's accommodation
    /// drifts by about ±0.25 D while it looks): each is a stacked target term, shown the document at
    /// `target_focus_weight`, and the target guard asks the target to read in each (docs/design.md §3.1).
    /// Empty: the `security` level's.
    pub target_focus_d: Vec<f64>,
    /// Pupil states the target must read in too, mm added to its viewing pupil (a pupil follows the light while
    /// one looks); a state that would pass the pupil the aberrations were measured over stops at it (nothing is
    /// known of the eye beyond), and one that changes nothing is dropped. Each is a stacked target term at
    /// `target_focus_weight` that the guard judges, as the focus states are. Empty: the `security` level's.
    pub target_pupil_mm: Vec<f64>,
    /// The weight of each target state's term (focus and pupil), relative to the profile's own look (1).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 4.0))]
    pub target_focus_weight: f64,
    /// Bystander camera rounds (0 = off): after each solve, the threat model's focus-sweeping camera (every
    /// focus and aperture of [`BystanderOptions::default`](crate::evaluation::BystanderOptions), behind the
    /// sensor's R, G and B and behind each band's filter) looks from `bystander_scan_mm` to the right, left,
    /// above and below the target, with the encoder's own kernel draw; up to `bystander_decoys_per_round` of the
    /// settings nearest to reading (as seen or unwarped: the known-font attacker's margin where the text is known,
    /// within [`BYSTANDER_NEAR_MARGIN`] of reading; else legibility at least 0.8 of the threshold) join as decoys,
    /// shown noise and held to the leak penalty, and the solve runs again from its end. A camera just past one of
    /// the display's repeats of the seat reads frames that hold the cameras at the seat (docs/experiments.md §2c).
    pub bystander_rounds: u32,
    /// Lateral offsets (mm) the bystander camera rounds look from, each in four directions.
    pub bystander_scan_mm: Vec<f64>,
    /// Camera settings added as decoys per bystander round at most.
    pub bystander_decoys_per_round: u32,
    /// Draws tried (1 = the seed alone): with n > 1 the whole encode runs for n seeds (`seed`, then seeds
    /// [`DRAW_SEED_STEP`] apart), each drawing its own population decoys, noise and kernels, and the light field
    /// kept is the draw that the encoder's own checks rank first: the target reads its view; then fewer than 1 %
    /// of [`DRAW_CHECK_PEOPLE`] fresh people at the seat read; then the fewest settings of the threat model's
    /// focus-sweeping camera read, at the seat and at its first repeat 10 mm or more away (right, left, above,
    /// below); then, with a head ring (`head_radius_mm` > 0) or
    /// head-box rounds, the most positions read on rings of 1–5 mm around the seat (right, left, above, below) by
    /// a tracked eye (frames re-indexed for it); then the fewest of those people read (half with pupils
    /// bracketing the target's when near-pupil decoys are asked), all through a kernel draw and from a
    /// seed stream the evaluation never uses, judged as the evaluation judges (the known-font attacker where the
    /// text is known; the legibility threshold, far more lenient, otherwise). A draw whose check held the seat is
    /// confirmed by [`DRAW_CONFIRM_PEOPLE`] more fresh people (sampled as the evaluation samples them, through a
    /// kernel draw of their own) before it may be kept, and one whose seat held under that confirmation is kept
    /// before any other: the best of several checks is biased low. The encoder's seed alone decides whether a
    /// head box holds (docs/experiments.md §2c).
    pub draws: u32,
    /// After the solve, check that the target reads its own view (the evaluation's judge); if not, halve every
    /// decoy's weight and leak weight and solve again from the last solve's end, until the target reads or the
    /// weights are down to an eighth of where they started and to 0.0375 (`GUARD_FLOOR_WEIGHT`) or below; then
    /// try the weight √2 above the one that read and keep it if the target still reads. Each lighter solve stops
    /// early where the target already reads its view clearly (`GUARD_EARLY_EVERY`), and a solve that another
    /// follows when the target misreads its end gives up where, with the text known, the target's margin cannot
    /// reach the one asked by the iteration cap at its pace (docs/design.md §3.1). The target's reading comes
    /// first: a display that cannot hide the document from the decoys then shows it to the target anyway, and
    /// the evaluation says who else reads.
    pub ensure_target_reads: bool,
    /// Where the document's text is known: the lead (in correlation) by which the target guard asks the
    /// known-font attacker's true glyph to beat the best other candidate in every cell of the target's view
    /// (`KnownFontRead::margin`), through both of its looks; 0 asks only that every character reads right. A
    /// view read right by a hair is misread under another sampling of the same eye's kernels.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 0.5))]
    pub target_margin: f64,
    /// The document's text, font scale and secret alphabet, when it is a PIN slip or form drawn in eyekey's
    /// font (`eyekey example document`): the job's evaluation then also reads every view with the known-font
    /// attacker. Write secret characters as `*` to describe the layout without the secret; their values are
    /// read from the document when the job runs.
    pub document_text: Option<crate::evaluation::DocumentText>,
}

/// At which focus the sampled decoys look ([`EncodeOptions::decoy_focus`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum DecoyFocus {
    /// Their profiles' own focus.
    Own,
    /// Each accommodated to the focus that brings their spherical equivalent nearest the target's, within the
    /// range the evaluation lets people refocus over (−1 to +2 D,
    /// [`Accommodation::matching`](crate::physics::accommodation::Accommodation::matching)): the people who refocus
    /// to read rather than people holding their own focus.
    Target,
    /// Both (the default): every sampled decoy at its own focus and again at the target's (twice the decoy
    /// terms). Of the three it is the one that keeps the people who refocus from reading without uncovering the
    /// people who hold their focus, while every held-out target still reads at ±0.25 D (docs/experiments.md §0).
    #[default]
    Both,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        Self {
            security: Security::Standard,
            method: Method::Multiplex,
            optics: Optics::Wave,
            ablation: None,
            population_decoys: 6,
            decoys_at_target_pupil: false,
            decoy_focus: DecoyFocus::Both,
            near_pupil_decoys: 6,
            near_pupil_ring_mm: 0.0,
            decoy: DecoyKind::Noise,
            decoy_weight: None,
            leak_weight: 3.0,
            leak_glyphs: true,
            leak_learned_reader: false,
            seed: None,
            sub_rays: 16,
            max_iterations: 300,
            tolerance: 1e-5,
            lambda_w: 0.05,
            lambda_c: 0.05,
            evaluation_population: 20,
            head_radius_mm: 0.0,
            head_positions: 4,
            head_weight: DEFAULT_HEAD_WEIGHT,
            adaptive_rounds: 0,
            adaptive_candidates: 24,
            adaptive_per_round: 4,
            camera_decoys: false,
            camera_decoy_focus_d: vec![-0.5, 0.5],
            camera_decoy_aperture_mm: 6.0,
            camera_decoy_extra_apertures_mm: vec![],
            camera_decoy_ring_mm: 0.0,
            head_rounds: 0,
            head_round_max_weight: HEAD_ROUND_MAX_WEIGHT,
            target_focus_d: Vec::new(),
            target_pupil_mm: Vec::new(),
            target_focus_weight: DEFAULT_TARGET_FOCUS_WEIGHT,
            bystander_rounds: 0,
            bystander_scan_mm: DEFAULT_BYSTANDER_SCAN_MM.to_vec(),
            bystander_decoys_per_round: 8,
            draws: 1,
            ensure_target_reads: true,
            target_margin: 0.0,
            document_text: None,
        }
    }
}

/// A seed from the operating system's CSPRNG (`getrandom`), for an encode that was given none.
pub fn fresh_seed() -> u64 {
    use rand::RngCore;
    rand::rngs::OsRng.next_u64()
}

/// The decoys' weight on the `secure` design when none is asked for: over 52 held-out targets and PIN slips,
/// 100 of 11,000 held-out people at the target's seat read its frames with the decoys at 0.5, against 135 at
/// [`DEFAULT_DECOY_WEIGHT`], and every target reads (docs/experiments.md §2e).
pub const SECURE_DECOY_WEIGHT: f64 = 0.5;

/// The decoys' weight on every other display when none is asked for. Over every preset's held-out targets 0.5
/// let more people read than 0.3 (22 of 540 against 15; docs/experiments.md §2e).
pub const DEFAULT_DECOY_WEIGHT: f64 = 0.3;

/// Where the bystander camera rounds look from by default (mm, each to the right, left, above and below): 10.8 to
/// 22 mm in steps of 0.8 mm, halfway between the points of the bystander experiment's fine scan (10, 11.2, 12, …
/// 20.8 mm), so that the experiment judges the frames from positions the encoder never looked from.
pub const DEFAULT_BYSTANDER_SCAN_MM: [f64; 15] = [
    10.8, 11.6, 12.4, 13.2, 14.0, 14.8, 15.6, 16.4, 17.2, 18.0, 18.8, 19.6, 20.4, 21.2, 22.0,
];

/// How far apart the seeds of successive draws are (`draws`): beyond every offset the encoder adds to its seed.
pub const DRAW_SEED_STEP: u64 = 1_000_003;

/// Fresh people at the seat each draw is checked with (`draws`).
pub const DRAW_CHECK_PEOPLE: u32 = 200;

/// Fresh people at the seat who confirm a draw whose check held the seat before it may be kept (`draws`): at
/// fewer than 1 % reading (3 of 400), a draw that lets 3.7 % read passes about once in 5,000, one that lets 2 % about once in 25.
pub const DRAW_CONFIRM_PEOPLE: u32 = 400;

/// Stacked positions a head-box round adds at most (`head_rounds`).
pub const HEAD_ROUND_MAX_ADDED: u32 = 4;

/// A head-box round multiplies the weight of a stacked position whose tracked eye still misreads by this
/// (`head_rounds`), up to `head_round_max_weight`: a position stacked at `head_weight` and misread after the
/// solve is asked for the document again, harder, instead of being left as it is.
pub const HEAD_ROUND_WEIGHT_STEP: f64 = 2.0;

/// The weight a head-box round raises a stacked position to at most by default (`head_round_max_weight`): the
/// design position's own (or `head_weight`, if larger).
pub const HEAD_ROUND_MAX_WEIGHT: f64 = 1.0;

/// The solve after an adaptive, head-box or bystander round runs at least this many iterations (or
/// `max_iterations`, if fewer) before it may stop as converged ([`SolverOptions::min_iterations`](crate::encoding::solver::SolverOptions)):
/// it starts from the last solve's end, and where the round changed little (a stacked position raised from 0.5
/// to 0.75) the tolerance test stopped it after 6 iterations, the target's head-box legibilities the same to two
/// decimals as without the raise (docs/experiments.md §2c).
pub const ROUND_SOLVE_MIN_ITERATIONS: u32 = 60;

/// Ring positions a head-box round looks from (`head_rounds`): 1–5 mm, right, left, above and below.
pub const HEAD_ROUND_POSITIONS: u32 = 20;

/// How near to reading a bystander camera setting must come to join as a decoy (`bystander_rounds`): the known-font
/// attacker's margin (the true glyph's smallest lead over the best other, negative when a character is misread)
/// at least minus this.
pub const BYSTANDER_NEAR_MARGIN: f64 = 0.02;

/// Each focus state's weight by default (`target_focus_weight`).
pub const DEFAULT_TARGET_FOCUS_WEIGHT: f64 = 0.5;

/// Each head-movement position's weight by default: a quarter of the design position's.
pub const DEFAULT_HEAD_WEIGHT: f64 = 0.25;

impl EncodeOptions {
    /// The decoys' weight when the options give none: [`SECURE_DECOY_WEIGHT`] on the `secure` design (a display
    /// whose geometry is [`DisplayGeometry::secure`]'s, however it was registered), [`DEFAULT_DECOY_WEIGHT`] on
    /// any other.
    pub fn default_decoy_weight(display: &DisplayGeometry) -> f64 {
        if *display == DisplayGeometry::secure() {
            SECURE_DECOY_WEIGHT
        } else {
            DEFAULT_DECOY_WEIGHT
        }
    }

    /// The decoys' weight on `display`: the one asked for, else the display's default.
    pub fn decoy_weight_on(&self, display: &DisplayGeometry) -> f64 {
        self.decoy_weight.unwrap_or_else(|| Self::default_decoy_weight(display))
    }

    /// The focus states the target must read in (dioptres): `target_focus_d`, else the `security` level's.
    pub fn focus_states_d(&self) -> Vec<f64> {
        match (self.target_focus_d.is_empty(), self.security) {
            (false, _) => self.target_focus_d.clone(),
            (true, Security::Standard) => STANDARD_FOCUS_STATES_D.to_vec(),
            (true, Security::Strict) => Vec::new(),
        }
    }

    /// The pupil states the target must read in (mm): `target_pupil_mm`, else the `security` level's.
    pub fn pupil_states_mm(&self) -> Vec<f64> {
        match (self.target_pupil_mm.is_empty(), self.security) {
            (false, _) => self.target_pupil_mm.clone(),
            (true, Security::Standard) => STANDARD_PUPIL_STATES_MM.to_vec(),
            (true, Security::Strict) => Vec::new(),
        }
    }

    /// These options with `seed` set: the one given, else a fresh one from the operating system's CSPRNG.
    pub fn with_fresh_seed(mut self) -> Self {
        if self.seed.is_none() {
            self.seed = Some(fresh_seed());
        }
        self
    }

    /// The seed of an encode whose options have been through [`EncodeOptions::with_fresh_seed`] (the pipeline
    /// does so on entry).
    ///
    /// # Panics
    /// If `seed` is absent: every path into the encoder resolves it first, and drawing one here would give each
    /// caller a different seed.
    pub fn drawn_seed(&self) -> u64 {
        self.seed
            .expect("the encoder resolves the seed (EncodeOptions::with_fresh_seed) before it draws anything")
    }

    /// These options with every display-dependent default filled in for `display`, as a job states them.
    pub fn for_display(mut self, display: &DisplayGeometry) -> Self {
        self.decoy_weight = Some(self.decoy_weight_on(display));
        self
    }

    /// Checks every option's range; errors name the field.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let bad = |field: &str, why: String| Err(PipelineError::invalid(format!("options.{field}"), why));
        if !(1..=256).contains(&self.sub_rays) {
            return bad("sub_rays", format!("must be within 1..=256, got {}", self.sub_rays));
        }
        if !(1..=20_000).contains(&self.max_iterations) {
            return bad(
                "max_iterations",
                format!("must be within 1..=20000, got {}", self.max_iterations),
            );
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0 && self.tolerance < 1.0) {
            return bad("tolerance", format!("must be within (0, 1), got {}", self.tolerance));
        }
        if self.near_pupil_decoys > 16 {
            return bad(
                "near_pupil_decoys",
                format!("at most 16, got {}", self.near_pupil_decoys),
            );
        }
        if self.population_decoys > 64 {
            return bad(
                "population_decoys",
                format!("at most 64, got {}", self.population_decoys),
            );
        }
        if let Some(w) = self.decoy_weight {
            if !(w.is_finite() && (0.0..=100.0).contains(&w)) {
                return bad("decoy_weight", format!("must be within 0..=100, got {w}"));
            }
        }
        for (name, v) in [
            ("lambda_w", self.lambda_w),
            ("lambda_c", self.lambda_c),
            ("leak_weight", self.leak_weight),
        ] {
            if !(v.is_finite() && (0.0..=100.0).contains(&v)) {
                return bad(name, format!("must be within 0..=100, got {v}"));
            }
        }
        if !(self.near_pupil_ring_mm.is_finite() && (0.0..=20.0).contains(&self.near_pupil_ring_mm)) {
            return bad(
                "near_pupil_ring_mm",
                format!("must be within 0..=20 mm, got {}", self.near_pupil_ring_mm),
            );
        }
        if !(self.camera_decoy_ring_mm.is_finite() && (0.0..=20.0).contains(&self.camera_decoy_ring_mm)) {
            return bad(
                "camera_decoy_ring_mm",
                format!("must be within 0..=20 mm, got {}", self.camera_decoy_ring_mm),
            );
        }
        for (field, states, what, unit) in [
            ("target_focus_d", &self.target_focus_d, "focus", "D"),
            ("target_pupil_mm", &self.target_pupil_mm, "pupil", "mm"),
        ] {
            if states.len() > 4 || states.iter().any(|d| !(d.is_finite() && d.abs() <= 2.0)) {
                return bad(
                    field,
                    format!("at most 4 {what} states within ±2 {unit}, got {states:?}"),
                );
            }
        }
        if !(self.target_focus_weight.is_finite() && (0.0..=4.0).contains(&self.target_focus_weight)) {
            return bad(
                "target_focus_weight",
                format!("must be within 0..=4, got {}", self.target_focus_weight),
            );
        }
        if !(self.target_margin.is_finite() && (0.0..=0.5).contains(&self.target_margin)) {
            return bad(
                "target_margin",
                format!("must be within 0..=0.5, got {}", self.target_margin),
            );
        }
        if !(self.head_radius_mm.is_finite() && (0.0..=20.0).contains(&self.head_radius_mm)) {
            return bad(
                "head_radius_mm",
                format!("must be within 0..=20 mm, got {}", self.head_radius_mm),
            );
        }
        for (name, v) in [
            ("head_weight", self.head_weight),
            ("head_round_max_weight", self.head_round_max_weight),
        ] {
            if !(v.is_finite() && (0.0..=4.0).contains(&v)) {
                return bad(name, format!("must be within 0..=4, got {v}"));
            }
        }
        if !(3..=16).contains(&self.head_positions) {
            return bad(
                "head_positions",
                format!("must be within 3..=16, got {}", self.head_positions),
            );
        }
        if self.adaptive_rounds > 5 || self.adaptive_candidates > 200 || self.adaptive_per_round > 16 {
            return bad(
                "adaptive_rounds",
                "at most 5 rounds of at most 200 candidates adding at most 16 decoys each".to_string(),
            );
        }
        if !(1..=8).contains(&self.draws) {
            return bad("draws", format!("must be within 1..=8, got {}", self.draws));
        }
        if self.head_rounds > 3 {
            return bad("head_rounds", format!("must be within 0..=3, got {}", self.head_rounds));
        }
        if self.head_rounds > 0 && self.optics != crate::physics::observer::Optics::Wave {
            return bad(
                "head_rounds",
                "the tracked eye is modelled under wave optics only (optics \"wave\")".to_string(),
            );
        }
        if self.bystander_rounds > 3 || self.bystander_decoys_per_round > 32 {
            return bad(
                "bystander_rounds",
                "at most 3 rounds adding at most 32 decoys each".to_string(),
            );
        }
        if self.bystander_scan_mm.len() > 32
            || self
                .bystander_scan_mm
                .iter()
                .any(|r| !(r.is_finite() && (0.5..=500.0).contains(r)))
        {
            return bad(
                "bystander_scan_mm",
                "at most 32 offsets, each within 0.5..=500 mm".to_string(),
            );
        }
        if self.camera_decoy_focus_d.len() > 9
            || self
                .camera_decoy_focus_d
                .iter()
                .any(|f| !(f.is_finite() && f.abs() <= 5.0))
        {
            return bad(
                "camera_decoy_focus_d",
                "at most 9 focus settings, each within ±5 D".to_string(),
            );
        }
        if !(self.camera_decoy_aperture_mm.is_finite() && (2.0..=10.0).contains(&self.camera_decoy_aperture_mm)) {
            return bad(
                "camera_decoy_aperture_mm",
                format!("must be within 2..=10 mm, got {}", self.camera_decoy_aperture_mm),
            );
        }
        if self.camera_decoy_extra_apertures_mm.len() > 3
            || self
                .camera_decoy_extra_apertures_mm
                .iter()
                .any(|a| !(a.is_finite() && (2.0..=10.0).contains(a)))
        {
            return bad(
                "camera_decoy_extra_apertures_mm",
                "at most 3 further apertures, each within 2..=10 mm".to_string(),
            );
        }
        if let Some(t) = &self.document_text {
            t.validate()
                .map_err(|e| PipelineError::invalid("options.document_text", e.to_string()))?;
        }
        if self.evaluation_population > 2000 {
            return bad(
                "evaluation_population",
                format!("at most 2000, got {}", self.evaluation_population),
            );
        }
        Ok(())
    }
}

pub(crate) fn aspect_matches(img: &image::RgbImage, display: &DisplayGeometry) -> bool {
    let a = img.width() as f64 / img.height() as f64;
    let b = display.holes_x as f64 / display.holes_y as f64;
    (a / b - 1.0).abs() <= 0.05
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_secure_design_weighs_its_decoys_at_one_half_and_every_other_display_at_three_tenths() {
        let secure = DisplayGeometry::secure();
        assert_eq!(EncodeOptions::default_decoy_weight(&secure), 0.5);
        for name in ["paper", "small", "lenslet", "pinhole", "dense"] {
            let d = DisplayGeometry::preset(name).unwrap();
            assert_eq!(EncodeOptions::default_decoy_weight(&d), 0.3, "{name}");
        }
        // The design, not the name: a registered geometry is the secure design after a JSON round trip (how the
        // service stores displays), and is not with one more lenslet a side.
        let stored: DisplayGeometry = serde_json::from_str(&serde_json::to_string(&secure).unwrap()).unwrap();
        assert_eq!(EncodeOptions::default_decoy_weight(&stored), 0.5);
        let wider = DisplayGeometry {
            holes_x: 33,
            ..secure.clone()
        };
        assert_eq!(EncodeOptions::default_decoy_weight(&wider), 0.3);
        // A weight asked for stands on every display; `for_display` states the one used.
        let asked = EncodeOptions {
            decoy_weight: Some(0.7),
            ..Default::default()
        };
        assert_eq!(asked.decoy_weight_on(&secure), 0.7);
        assert_eq!(asked.clone().for_display(&wider).decoy_weight, Some(0.7));
        assert_eq!(EncodeOptions::default().for_display(&secure).decoy_weight, Some(0.5));
        assert_eq!(EncodeOptions::default().for_display(&wider).decoy_weight, Some(0.3));
    }

    #[test]
    fn a_decoy_weight_out_of_range_is_refused_by_name() {
        for w in [-0.1, 100.5, f64::NAN, f64::INFINITY] {
            let o = EncodeOptions {
                decoy_weight: Some(w),
                ..Default::default()
            };
            let e = o.validate().unwrap_err().to_string();
            assert!(e.contains("decoy_weight"), "{e}");
        }
        assert!(EncodeOptions::default().validate().is_ok());
    }

    #[test]
    fn bystander_rounds_are_bounded_and_their_scan_sits_between_the_fine_scan_points() {
        let refused = |o: EncodeOptions, field: &str| {
            let e = o.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        let with = |f: fn(&mut EncodeOptions)| {
            let mut o = EncodeOptions {
                bystander_rounds: 1,
                ..Default::default()
            };
            f(&mut o);
            o
        };
        assert!(with(|_| {}).validate().is_ok());
        refused(with(|o| o.bystander_rounds = 4), "bystander_rounds");
        refused(with(|o| o.bystander_decoys_per_round = 33), "bystander_rounds");
        refused(with(|o| o.bystander_scan_mm = vec![0.2]), "bystander_scan_mm");
        refused(with(|o| o.bystander_scan_mm = vec![f64::NAN]), "bystander_scan_mm");
        refused(with(|o| o.bystander_scan_mm = vec![12.0; 33]), "bystander_scan_mm");
        // 0.4 mm from every point of the bystander experiment's fine scan (10, 11.2, 12, … 20.8 mm).
        let fine = [10.0, 11.2, 12.0, 12.8, 13.6, 14.4, 17.6, 18.4, 19.2, 20.0, 20.8, 25.6];
        for r in DEFAULT_BYSTANDER_SCAN_MM {
            let nearest = fine.iter().map(|f| (f - r).abs()).fold(f64::INFINITY, f64::min);
            assert!(nearest > 0.39, "{r}");
        }
        assert_eq!(EncodeOptions::default().bystander_rounds, 0, "off by default");
    }

    #[test]
    fn head_box_rounds_are_bounded_and_need_wave_optics() {
        let with = |rounds: u32, optics: Optics| EncodeOptions {
            head_rounds: rounds,
            optics,
            ..Default::default()
        };
        assert!(with(3, Optics::Wave).validate().is_ok());
        for refused in [with(4, Optics::Wave), with(1, Optics::Geometric)] {
            let e = refused.validate().unwrap_err().to_string();
            assert!(e.contains("head_rounds"), "{e}");
        }
        assert!(with(0, Optics::Geometric).validate().is_ok());
        assert_eq!(EncodeOptions::default().head_rounds, 0, "off by default");
    }

    /// Options with one weight set by `set` are refused, naming `field`, at each of `refused`, and accepted at
    /// each of `accepted`.
    fn weight_bounds(set: fn(&mut EncodeOptions, f64), field: &str, refused: &[f64], accepted: &[f64]) {
        let with = |w: f64| {
            let mut o = EncodeOptions::default();
            set(&mut o, w);
            o
        };
        for &w in refused {
            let e = with(w).validate().unwrap_err().to_string();
            assert!(e.contains(field), "{w}: {e}");
        }
        for &w in accepted {
            assert!(with(w).validate().is_ok(), "{field} {w}");
        }
    }

    #[test]
    fn a_head_weight_out_of_range_is_refused_by_name_and_a_quarter_is_the_default() {
        assert_eq!(EncodeOptions::default().head_weight, 0.25);
        weight_bounds(
            |o, w| o.head_weight = w,
            "head_weight",
            &[-0.01, 4.01, f64::NAN],
            &[0.0, 0.4, 4.0],
        );
    }

    #[test]
    fn a_head_round_cap_out_of_range_is_refused_by_name_and_the_seat_s_weight_is_the_default() {
        assert_eq!(EncodeOptions::default().head_round_max_weight, 1.0);
        weight_bounds(
            |o, w| o.head_round_max_weight = w,
            "head_round_max_weight",
            &[-0.01, 4.01, f64::NAN, f64::INFINITY],
            &[0.0, 0.5, 4.0],
        );
    }
}
