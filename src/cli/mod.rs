//! The `eyekey` command line: the same pipeline as the service, offline, on files.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};

use eyekey_core::encoding::options::{Ablation, DecoyKind, Method};
use eyekey_core::imaging;
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::Optics;
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportCache, TransportOptions};
use eyekey_core::physics::zernike::{Prescription, ZernikeCoefficients};

/// eyekey: show a document on a light-field display so that only one enrolled person can read it.
#[derive(Parser, Debug)]
#[command(name = "eyekey", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print example JSON to start from.
    #[command(subcommand)]
    Example(ExampleCommand),
    /// Inspect a display description.
    #[command(subcommand)]
    Display(DisplayCommand),
    /// Render what a person sees of an image shown plainly on the display, or of a frame bundle.
    Simulate(SimulateArgs),
    /// Encode a document into a frame bundle that only the target can read.
    Encode(EncodeArgs),
    /// Measure who can read a frame bundle: target, observers, a sampled population, a camera.
    Evaluate(EvaluateArgs),
    /// Benchmarks: transport build, sparse kernels, solver, whole encode; figures go to a Markdown file.
    Bench(BenchArgs),
    /// Experiments: the paper's §7.3, a design-space sweep, the secure preset's evaluation.
    #[command(subcommand)]
    Experiment(ExperimentCommand),
    /// Run the REST service (embedded SQLite or PostgreSQL, durable job queue, frame bundles for
    /// registered displays).
    Serve(crate::service::ServeArgs),
    /// Run job workers with no API, on a PostgreSQL database shared with `eyekey serve` processes.
    Worker(crate::service::WorkerArgs),
    /// Run a display client: fetch this display's newest frame bundle, verify it and install it into
    /// `<out>/current/`, once or following the server's events.
    DisplayClient(crate::client::DisplayClientArgs),
}

/// `eyekey display ...`
#[derive(Subcommand, Debug)]
pub enum DisplayCommand {
    /// Per band: the view spacing at the pupil, a view's diffraction spread there, the resolvability
    /// M = A·s/(λd) and how many views a 4 mm and a 6 mm pupil resolve.
    Check {
        /// The display description (JSON).
        #[arg(long)]
        display: PathBuf,
        /// Print the figures as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Head tracking: re-index a bundle's frames for the eye position a tracker reports (sideways, at the
    /// design distance), so the target keeps reading without a new encode; writes a new bundle.
    Track {
        /// The bundle (directory) encoded for the design position.
        #[arg(long)]
        bundle: PathBuf,
        /// The tracked eye's offset to the right of the design position, mm.
        #[arg(long, allow_hyphen_values = true)]
        eye_x: f64,
        /// The tracked eye's vertical offset (along the display's y axis), mm.
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.0)]
        eye_y: f64,
        /// Output directory (must not exist).
        #[arg(long)]
        out: PathBuf,
    },
}

/// `eyekey experiment ...`
#[derive(Subcommand, Debug)]
pub enum ExperimentCommand {
    /// Paper §7.3: Fig. 13 baseline, Fig. 14 multiplex and Fig. 15 difference maximisation, with both ablations.
    Paper {
        /// Output directory.
        #[arg(long, default_value = "docs/experiments/paper")]
        out: PathBuf,
        /// Solver iteration cap per encoding.
        #[arg(long, default_value_t = 300)]
        max_iterations: u32,
        /// People sampled to check the proposed multiplex encoding (0 skips).
        #[arg(long, default_value_t = 50)]
        population: u32,
        /// Forward model of the encoders and of every viewer: geometric (the paper's idealisation) or wave.
        #[arg(long, value_enum, default_value = "geometric")]
        optics: Optics,
    },
    /// Design-space sweep: target legibility against the fraction of a sampled population that can read.
    Sweep {
        /// Output directory [default: docs/experiments/sweep-wave, or docs/experiments/sweep under geometric].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Forward model and configurations: wave (lenslet and pinhole displays that resolve their views) or
        /// geometric (the configurations the `secure` preset was chosen from).
        #[arg(long, value_enum, default_value = "wave")]
        optics: Optics,
        /// People sampled per configuration.
        #[arg(long, default_value_t = 60)]
        population: u32,
        /// Solver iteration cap per encoding.
        #[arg(long, default_value_t = 200)]
        max_iterations: u32,
    },
    /// A PIN slip on the wave sweep's lenslet baseline, looked at by people and a focus-sweeping camera from a
    /// grid of positions beside and above the target, at its viewing distance.
    Bystanders {
        /// Output directory.
        #[arg(long, default_value = "docs/experiments/bystanders")]
        out: PathBuf,
        /// People sampled at every position.
        #[arg(long, default_value_t = 6)]
        people: u32,
        /// Offsets from the target's pupil at its viewing distance, mm, each looked at to the right, left,
        /// above and below (`--lateral` alone: none).
        #[arg(long, num_args = 0.., value_delimiter = ',', default_values_t = vec![10.0, 20.0, 50.0, 100.0, 200.0, 500.0])]
        lateral: Vec<f64>,
        /// Other viewing distances, mm from the barrier, nearer and farther than the target (empty: none).
        #[arg(long, num_args = 0.., value_delimiter = ',')]
        distances: Vec<f64>,
        /// Offsets to the right looked at at each of `--distances`, mm.
        #[arg(long, value_delimiter = ',', default_values_t = vec![0.0, 50.0, 200.0])]
        lateral_at_distance: Vec<f64>,
        /// Camera apertures tried at every position, mm (`--camera-apertures` alone: no camera).
        #[arg(long, num_args = 0.., value_delimiter = ',', default_values_t = vec![2.0, 4.0, 8.0])]
        camera_apertures: Vec<f64>,
        /// Solver iteration cap per encoding.
        #[arg(long, default_value_t = 200)]
        max_iterations: u32,
        /// Sub-rays per sample of the bystanders' and cameras' kernels (more: nearer the views a real eye or
        /// lens forms, less Monte Carlo noise; the time grows with them).
        #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u32).range(1..=1024))]
        evaluation_sub_rays: u32,
        /// Only the encodings whose label contains this text.
        #[arg(long)]
        only: Option<String>,
        #[command(flatten)]
        overrides: crate::research::bystanders::Overrides,
    },
    /// The target's head box on the wave sweep's lenslet baseline: fixed frames, frames re-indexed for the
    /// tracked eye, and the target stacked on rings; with the share of people at the design position who read.
    Headbox {
        /// Output directory.
        #[arg(long, default_value = "docs/experiments/headbox")]
        out: PathBuf,
        /// People sampled at the design position per encoding.
        #[arg(long, default_value_t = 1000)]
        population: u32,
        /// Solver iteration cap per encoding.
        #[arg(long, default_value_t = 200)]
        max_iterations: u32,
        /// Only the rows whose label contains this text, or one of several separated by `|` (the table is then
        /// written to `headbox-only.md`).
        #[arg(long)]
        only: Option<String>,
        /// Also look at the same people at the design position through this many more kernel draws, and
        /// through kernels near their expectation (the target guard's sub-rays), each counted apart.
        #[arg(long, default_value_t = 0)]
        seat_kernel_draws: u32,
        #[command(flatten)]
        overrides: crate::research::bystanders::Overrides,
    },
    /// The encoder frontier on the wave sweep's lenslet baseline: each encoder variant's target reading against
    /// the share of held-out people and of camera settings at the target's position that read.
    Encoders {
        /// Output directory.
        #[arg(long, default_value = "docs/experiments/encoders")]
        out: PathBuf,
        /// Held-out people at the target's position per variant.
        #[arg(long, default_value_t = 1000)]
        population: u32,
        /// Solver iteration cap per encoding.
        #[arg(long, default_value_t = 200)]
        max_iterations: u32,
        /// Only the variants whose label contains this text.
        #[arg(long)]
        only: Option<String>,
    },
    /// Every preset's default encode on held-out targets and PIN slips: does the target read, and who else?
    Defaults {
        /// Output directory.
        #[arg(long, default_value = "docs/experiments/defaults")]
        out: PathBuf,
        /// Held-out targets per preset.
        #[arg(long, default_value_t = 3)]
        targets: u32,
        /// Held-out people at the target's position per encoding.
        #[arg(long, default_value_t = 30)]
        population: u32,
        /// The target's view drawn again with this many other evaluation seeds, each read by the known-font
        /// attacker.
        #[arg(long, default_value_t = 4)]
        target_looks: u32,
        /// Only these presets (repeatable; default all).
        #[arg(long)]
        preset: Vec<String>,
        /// The decoys look through the target's pupil (`decoys_at_target_pupil`).
        #[arg(long)]
        decoys_at_target_pupil: bool,
        /// At which focus the sampled decoys look (`decoy_focus`).
        #[arg(long, value_enum, default_value = "both")]
        decoy_focus: eyekey_core::encoding::pipeline::DecoyFocus,
        /// The leak penalty also covers the shipped learned reader's directions (`leak_learned_reader`).
        #[arg(long)]
        leak_learned_reader: bool,
        /// Encode each slip as an uploaded image, without its text hint (the evaluation still reads it with the
        /// known-font attacker).
        #[arg(long)]
        no_hint: bool,
        /// How hard to hide, at what cost to the target's comfort (`security`).
        #[arg(long, value_enum, default_value = "standard")]
        security: eyekey_core::encoding::pipeline::Security,
        /// Instead of the security level's: focus states the target must read in too (repeatable;
        /// `target_focus_d`).
        #[arg(long, allow_hyphen_values = true)]
        target_focus: Vec<f64>,
        /// Instead of the security level's: pupil states the target must read in too (repeatable;
        /// `target_pupil_mm`).
        #[arg(long, allow_hyphen_values = true)]
        target_pupil: Vec<f64>,
        /// Draws tried, the best kept by the encoder's own check (`draws`).
        #[arg(long, default_value_t = 1)]
        draws: u32,
        /// The held-out targets' pupils are drawn uniformly in 3–7 mm, their aberrations stated over 7.5 mm,
        /// instead of the population's 4–7 mm.
        #[arg(long)]
        wide_pupils: bool,
        /// The documents in this font instead of eyekey's, a file name in Debian's font directories such as
        /// `DejaVuSerif.ttf` (`bash tests/fonts/install.sh` installs them), encoded as uploaded images (eyekey's
        /// text hint describes its own font only); the experiment's known-font attacker is drawn in it.
        #[arg(long)]
        font: Option<String>,
        /// With `--font`: documents of two lines of text ("A" and "B", each with four digits) instead of PIN
        /// slips.
        #[arg(long)]
        two_lines: bool,
        /// Instead of the default: population decoys.
        #[arg(long)]
        decoys: Option<u32>,
        /// Instead of the default (0.5 on `secure`, 0.3 on the others): the decoys' weight.
        #[arg(long)]
        decoy_weight: Option<f64>,
        /// Instead of the default: the decoys' leak penalty weight.
        #[arg(long)]
        leak_weight: Option<f64>,
        /// Instead of the default: decoys whose pupils bracket the target's (`near_pupil_decoys`).
        #[arg(long)]
        near_pupil_decoys: Option<u32>,
        /// Instead of the default: sub-rays per sample in the encoder's transport.
        #[arg(long)]
        sub_rays: Option<u32>,
        /// Instead of the default: the known-font margin the target guard asks of the target's view.
        #[arg(long)]
        target_margin: Option<f64>,
        /// Instead of the experiments' fixed seed (1): the encoder's seed, which draws the population decoys, the
        /// noise they are shown and the kernels' sub-rays (the held-out targets and people stay the same).
        #[arg(long)]
        seed: Option<u64>,
        /// Instead of the default: rounds that add as decoys the sampled candidates who still read
        /// (`adaptive_rounds`).
        #[arg(long)]
        adaptive_rounds: Option<u32>,
    },
    /// The views a learned reader trains and is tested on: PIN slips for sampled targets, each encoding with its
    /// own fresh seed, seen by fresh people at the seat (at their own focus and refocused), beside it, by
    /// one-band cameras and by the target (`benches/learned_reader/run.sh` trains and tests the readers).
    ReaderViews {
        /// Output directory (views.f32 and views.json).
        #[arg(long)]
        out: PathBuf,
        /// Display preset.
        #[arg(long, default_value = "secure")]
        preset: String,
        /// Encodings, each its own target, PIN and seed.
        #[arg(long, default_value_t = 160)]
        encodings: u32,
        /// The first encoding's index (runs with different starts make disjoint encodings).
        #[arg(long, default_value_t = 0)]
        first: u32,
        /// Fresh people per encoding.
        #[arg(long, default_value_t = 40)]
        people: u32,
        /// How hard to hide (`security`).
        #[arg(long, value_enum, default_value = "standard")]
        security: eyekey_core::encoding::pipeline::Security,
        /// At which focus the sampled decoys look (`decoy_focus`).
        #[arg(long, value_enum, default_value = "both")]
        decoy_focus: eyekey_core::encoding::pipeline::DecoyFocus,
    },
    /// Encode a PIN slip on the `secure` preset and evaluate it against a large population sample.
    Secure {
        /// Output directory (bundle/ and evaluation/).
        #[arg(long, default_value = "docs/experiments/secure")]
        out: PathBuf,
        /// People sampled.
        #[arg(long, default_value_t = 1000)]
        population: u32,
    },
    /// Frames encoded under the geometric model, seen under the geometric and the wave model.
    Wave {
        /// Output directory (results.md and pictures).
        #[arg(long, default_value = "docs/experiments/wave")]
        out: PathBuf,
        /// Display preset.
        #[arg(long, default_value = "secure")]
        preset: String,
        /// Also compute the target's views by the independent Fourier-optics model (minutes per view).
        #[arg(long)]
        fourier: bool,
    },
    /// Simulated views with known text, their legibility and the known-font attacker's readings, for
    /// calibrating the threshold (calibration.md; `benches/calibrate_ocr.sh` adds OCR).
    Calibrate {
        /// Output directory (view_<k>.png, views.csv, calibration.md).
        #[arg(long, default_value = "target/calibration")]
        out: PathBuf,
        /// Number of views.
        #[arg(long, default_value_t = 400)]
        count: usize,
        /// Seed of the PINs, people and encodings.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// Options of `eyekey bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Display preset to benchmark.
    #[arg(long, default_value = "paper")]
    pub preset: String,
    /// Sub-rays per light-field sample.
    #[arg(long, default_value_t = 16)]
    pub sub_rays: u32,
    /// Which benchmark: transport, wave, kernels (their sampling noise), solver, encode, job (the `secure` default job
    /// end to end) or all; or scale (PostgreSQL, two API processes, 1/2/4 worker processes; not part of all).
    #[arg(long, default_value = "all")]
    pub section: String,
    /// For `--section scale`: an existing PostgreSQL server's URL (default: a throwaway server started by
    /// tests/postgres/server.sh); each worker count gets a new database on it.
    #[arg(long, hide_env_values = true)]
    pub database_url: Option<String>,
    /// Markdown file whose `<!-- bench:… -->` sections are replaced with the new figures.
    #[arg(long, default_value = "BENCHMARKS.md")]
    pub out: PathBuf,
    /// Also export the 2-observer solver problem (Matrix Market) into this directory for an external solver.
    #[arg(long)]
    pub export: Option<PathBuf>,
    /// For `--section job`: the job with this many near-pupil decoys instead of the default
    /// (`near_pupil_decoys`); its figures go to their own section, `job-near-pupil`.
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=16))]
    pub near_pupil_decoys: Option<u32>,
    /// For `--section job`: the job with its decoys at this weight instead of the display's default
    /// (`decoy_weight`); its figures go to their own section, `job-decoy-weight`.
    #[arg(long)]
    pub decoy_weight: Option<f64>,
}

/// The text hint of `eyekey encode` and `eyekey evaluate`.
#[derive(Args, Debug)]
pub struct TextHintArgs {
    /// The document's text as drawn by `eyekey example document` (repeat per line; write secret characters
    /// as `*` to have them read from the document): the known-font attacker then judges every view, the
    /// target's included (without it, the target must reach the legibility at which a reader almost surely
    /// reads, docs/legibility-calibration.md).
    #[arg(long)]
    pub text: Vec<String>,
    /// Pixels per font dot of --text, as drawn (`eyekey example document --scale`).
    #[arg(long, default_value_t = 4)]
    pub text_scale: u32,
    /// The secret characters' alphabet of --text.
    #[arg(long, default_value = "0123456789")]
    pub alphabet: String,
}

impl TextHintArgs {
    /// The hint as given (None without --text); the encoder and the evaluation check it against the document.
    pub fn hint(&self) -> Option<eyekey_core::evaluation::DocumentText> {
        (!self.text.is_empty()).then(|| eyekey_core::evaluation::DocumentText {
            lines: self.text.clone(),
            scale: self.text_scale,
            alphabet: self.alphabet.clone(),
        })
    }
}

/// Options of `eyekey encode`.
#[derive(Args, Debug)]
pub struct EncodeArgs {
    /// Display description (JSON).
    #[arg(long)]
    pub display: PathBuf,
    /// The target's vision profile (JSON).
    #[arg(long)]
    pub target: PathBuf,
    /// A representative observer's profile, shown the decoy (repeatable).
    #[arg(long)]
    pub observer: Vec<PathBuf>,
    /// A decoy image for the observers (implies --decoy-kind image).
    #[arg(long)]
    pub decoy: Option<PathBuf>,
    /// What decoy observers see: noise, grey or image.
    #[arg(long, value_enum)]
    pub decoy_kind: Option<DecoyKind>,
    /// Decoy observers sampled from the population.
    #[arg(long)]
    pub population_decoys: Option<u32>,
    /// Further decoys whose pupils bracket the target's (0.3 mm narrower to 0.7 mm wider; for small-pupil
    /// targets, docs/experiments.md §2e).
    #[arg(long)]
    pub near_pupil_decoys: Option<u32>,
    /// Also look at each near-pupil decoy on a ring of this radius (mm) around the target's position: for
    /// frames whose target is stacked on a ring (`--head-radius`).
    #[arg(long)]
    pub near_pupil_ring: Option<f64>,
    /// Weight of each decoy observer relative to the target (default: 0.5 on the `secure` design, 0.3 on others).
    #[arg(long)]
    pub decoy_weight: Option<f64>,
    /// Weight of the leak penalty on every decoy (0 = off; docs/design.md §3.1).
    #[arg(long)]
    pub leak_weight: Option<f64>,
    /// Keep the decoys' weights even when the target then cannot read its own view.
    #[arg(long)]
    pub no_target_guard: bool,
    /// The known-font margin the target guard asks of the target's view (`target_margin`).
    #[arg(long)]
    pub target_margin: Option<f64>,
    /// The encoder's seed, to reproduce an earlier encode (its `encoding.json` names it) or for experiments only.
    /// Without it (the default), a fresh seed is drawn from the operating system's CSPRNG: a seed anybody knows
    /// is a noise pattern an attacker can learn and subtract from the frames.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The document (PNG or JPEG).
    #[arg(long)]
    pub document: PathBuf,
    /// The document's text, font scale and secret alphabet, where it was drawn by eyekey.
    #[command(flatten)]
    pub hint: TextHintArgs,
    /// How hard to hide, at what cost to the target's comfort: `standard` asks the target to read while its
    /// focus drifts ±0.25 D and its pupil ±0.5 mm; `strict` lets the fewest people at the seat read and asks
    /// the target to hold its profile's focus (docs/experiments.md §0).
    #[arg(long, value_enum, default_value = "standard")]
    pub security: eyekey_core::encoding::pipeline::Security,
    /// Instead of the security level's: a focus state the target must read in too, dioptres added to its
    /// sphere (repeatable; `target_focus_d`).
    #[arg(long, allow_hyphen_values = true)]
    pub target_focus: Vec<f64>,
    /// Instead of the security level's: a pupil state the target must read in too, mm added to its viewing
    /// pupil (repeatable; `target_pupil_mm`).
    #[arg(long, allow_hyphen_values = true)]
    pub target_pupil: Vec<f64>,
    /// Encoder.
    #[arg(long, value_enum, default_value = "multiplex")]
    pub method: Method,
    /// Forward model the encoder inverts: wave (diffraction at the apertures, the eye's chromatic defocus,
    /// light through neighbouring blocks) or geometric (the paper's straight rays).
    #[arg(long, value_enum, default_value = "wave")]
    pub optics: Optics,
    /// Ablation: optical or spectral.
    #[arg(long, value_enum)]
    pub ablation: Option<Ablation>,
    /// Solver iteration cap.
    #[arg(long)]
    pub max_iterations: Option<u32>,
    /// Solver relative tolerance.
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Sub-rays per light-field sample.
    #[arg(long)]
    pub sub_rays: Option<u32>,
    /// λ_W of Eq. 16.
    #[arg(long)]
    pub lambda_w: Option<f64>,
    /// λ_c of Eq. 16.
    #[arg(long)]
    pub lambda_c: Option<f64>,
    /// Also make the target read from eye positions this far off axis, mm (head movement).
    #[arg(long)]
    pub head_radius: Option<f64>,
    /// The weight of each of those positions, relative to the design position's 1 (default 0.25).
    #[arg(long)]
    pub head_weight: Option<f64>,
    /// Adaptive decoy rounds: add sampled people who can still read as decoys and solve again.
    #[arg(long)]
    pub adaptive_rounds: Option<u32>,
    /// Add camera decoys: an ideal lens behind a one-band filter, shown noise.
    #[arg(long)]
    pub camera_decoys: bool,
    /// Also look at the camera decoys from four positions on a ring of this radius (mm) around the target's:
    /// for frames whose target is stacked on a ring (`--head-radius`).
    #[arg(long)]
    pub camera_decoy_ring: Option<f64>,
    /// Output bundle directory (must not exist): the bundle (the files its manifest lists) and, beside it, the
    /// operator's `encoding.json` with the seed, which must not go to a display.
    #[arg(long)]
    pub out: PathBuf,
}

/// Options of `eyekey evaluate`.
#[derive(Args, Debug)]
pub struct EvaluateArgs {
    /// Frame bundle directory or zip.
    #[arg(long)]
    pub bundle: PathBuf,
    /// The target's vision profile.
    #[arg(long)]
    pub target: PathBuf,
    /// The document the bundle encodes.
    #[arg(long)]
    pub document: PathBuf,
    /// Further observers to score (repeatable).
    #[arg(long)]
    pub observer: Vec<PathBuf>,
    /// People sampled from the population statistics.
    #[arg(long, default_value_t = 50)]
    pub population: u32,
    /// Seed of the population sample.
    #[arg(long, default_value_t = 20_000)]
    pub seed: u64,
    /// Legibility threshold.
    #[arg(long, default_value_t = eyekey_core::evaluation::DEFAULT_THRESHOLD)]
    pub threshold: f64,
    /// Forward model of every simulated view: wave or geometric.
    #[arg(long, value_enum, default_value = "wave")]
    pub optics: Optics,
    /// The document's text, font scale and secret alphabet, where it was drawn by eyekey.
    #[command(flatten)]
    pub hint: TextHintArgs,
    /// Output directory (report.json, views/).
    #[arg(long)]
    pub out: PathBuf,
}

/// `eyekey example ...`
#[derive(Subcommand, Debug)]
pub enum ExampleCommand {
    /// A display description.
    Display {
        /// Preset: paper, secure, small, lenslet, pinhole or dense.
        #[arg(long, default_value = "paper")]
        preset: String,
    },
    /// A vision profile (no options: a perfect eye, standard observer, 6 mm pupil).
    Profile(ExampleProfileArgs),
    /// A test document: lines of text, black on white, as a PNG.
    Document {
        /// A line of text (repeat for more lines); digits, letters and : - . , #.
        #[arg(long, default_value = "PIN 4821")]
        text: Vec<String>,
        /// Width in pixels.
        #[arg(long, default_value_t = 200)]
        width: u32,
        /// Height in pixels.
        #[arg(long, default_value_t = 200)]
        height: u32,
        /// Pixels per font dot.
        #[arg(long, default_value_t = 4)]
        scale: u32,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Options of `eyekey example profile`.
#[derive(Args, Debug)]
pub struct ExampleProfileArgs {
    /// Spherical refractive error, dioptres.
    #[arg(long, allow_hyphen_values = true)]
    pub sphere: Option<f64>,
    /// Cylinder, dioptres.
    #[arg(long, allow_hyphen_values = true, requires = "axis")]
    pub cylinder: Option<f64>,
    /// Cylinder axis, degrees.
    #[arg(long)]
    pub axis: Option<f64>,
    /// Pupil diameter, mm.
    #[arg(long, default_value_t = 6.0)]
    pub pupil: f64,
    /// Print a person sampled from the population statistics with this seed instead.
    #[arg(long, conflicts_with_all = ["sphere", "cylinder", "axis"])]
    pub population_seed: Option<u64>,
}

/// Options of `eyekey simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Display description (JSON).
    #[arg(long)]
    pub display: PathBuf,
    /// The viewer's vision profile (JSON).
    #[arg(long)]
    pub profile: PathBuf,
    /// An image shown plainly (every view of a hole equal).
    #[arg(long, conflicts_with = "frames", required_unless_present = "frames")]
    pub image: Option<PathBuf>,
    /// A frame bundle directory (or .zip) written by `eyekey encode` or downloaded from the service.
    #[arg(long)]
    pub frames: Option<PathBuf>,
    /// Output PNG (sRGB).
    #[arg(long)]
    pub out: PathBuf,
    /// Lateral eye offset, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub eye_x: f64,
    /// Vertical eye offset, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub eye_y: f64,
    /// Change of viewing distance, mm (positive = farther than the display's design distance).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub eye_z: f64,
    /// Forward model: wave (diffraction, chromatic defocus, light through neighbouring blocks, physical
    /// brightness) or geometric (the paper's straight rays).
    #[arg(long, value_enum, default_value = "wave")]
    pub optics: Optics,
    /// Sub-rays per light-field sample.
    #[arg(long, default_value_t = 16)]
    pub sub_rays: u32,
    /// Retinal pixels per hole pitch.
    #[arg(long, default_value_t = 2)]
    pub oversample: u32,
}

/// Reads and validates a display description.
pub fn read_display(path: &Path) -> Result<DisplayGeometry> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read display {}", path.display()))?;
    let d: DisplayGeometry =
        serde_json::from_str(&text).with_context(|| format!("display {}: malformed JSON", path.display()))?;
    d.validate().with_context(|| format!("display {}", path.display()))?;
    Ok(d)
}

/// Reads and validates a vision profile.
pub fn read_profile(path: &Path) -> Result<VisionProfile> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read profile {}", path.display()))?;
    VisionProfile::from_json(&text).with_context(|| format!("profile {}", path.display()))
}

/// Runs the command line; errors are reported by `main` on one line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Example(ExampleCommand::Display { preset }) => {
            let d = DisplayGeometry::preset(&preset)?;
            print_stdout(&serde_json::to_string_pretty(&d)?)?;
        }
        Command::Example(ExampleCommand::Profile(a)) => {
            print_stdout(&serde_json::to_string_pretty(&example_profile(&a)?)?)?;
        }
        Command::Example(ExampleCommand::Document {
            text,
            width,
            height,
            scale,
            out,
        }) => {
            if !(8..=4096).contains(&width) || !(8..=4096).contains(&height) {
                bail!("--width and --height must be within 8..=4096 pixels");
            }
            let lines: Vec<&str> = text.iter().map(String::as_str).collect();
            imaging::save_rgb_png(
                &eyekey_core::imaging::glyphs::render_text(&lines, width, height, scale),
                &out,
            )?;
        }
        Command::Display(DisplayCommand::Check { display, json }) => display_check(&display, json)?,
        Command::Display(DisplayCommand::Track {
            bundle,
            eye_x,
            eye_y,
            out,
        }) => {
            let (mu, mv) = crate::client::track_bundle(&bundle, eye_x, eye_y, &out)?;
            println!(
                "wrote {} re-indexed by ({mu}, {mv}) views for the eye at ({eye_x}, {eye_y}) mm",
                out.display()
            );
        }
        Command::Simulate(a) => simulate(&a)?,
        Command::Encode(a) => encode(&a)?,
        Command::Evaluate(a) => evaluate(&a)?,
        Command::Bench(a) => crate::research::bench::run(&a)?,
        Command::Serve(args) => {
            init_tracing();
            let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
            rt.block_on(crate::service::serve(args))?;
        }
        Command::Worker(args) => {
            init_tracing();
            let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
            rt.block_on(crate::service::worker(args))?;
        }
        Command::DisplayClient(args) => {
            init_tracing();
            let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
            rt.block_on(crate::client::run(args))?;
        }
        Command::Experiment(ExperimentCommand::Paper {
            out,
            max_iterations,
            population,
            optics,
        }) => {
            print!(
                "{}",
                crate::research::experiment::paper(&out, max_iterations, population, optics)?
            );
        }
        Command::Experiment(ExperimentCommand::Sweep {
            out,
            optics,
            population,
            max_iterations,
        }) => {
            let out = out.unwrap_or_else(|| match optics {
                Optics::Wave => PathBuf::from("docs/experiments/sweep-wave"),
                Optics::Geometric => PathBuf::from("docs/experiments/sweep"),
            });
            print!(
                "{}",
                crate::research::experiment::sweep(&out, population, max_iterations, optics)?.0
            );
        }
        Command::Experiment(ExperimentCommand::Bystanders {
            out,
            people,
            lateral,
            distances,
            lateral_at_distance,
            camera_apertures,
            max_iterations,
            evaluation_sub_rays,
            only,
            overrides,
        }) => {
            let bystanders = eyekey_core::evaluation::BystanderOptions {
                lateral_mm: lateral,
                distances_mm: distances,
                lateral_at_distance_mm: lateral_at_distance,
                people,
                camera_apertures_mm: camera_apertures,
                ..Default::default()
            };
            print!(
                "{}",
                crate::research::bystanders::run(
                    &out,
                    bystanders,
                    max_iterations,
                    evaluation_sub_rays,
                    only.as_deref(),
                    overrides
                )?
            );
        }
        Command::Experiment(ExperimentCommand::Headbox {
            out,
            population,
            max_iterations,
            only,
            seat_kernel_draws,
            overrides,
        }) => {
            print!(
                "{}",
                crate::research::bystanders::headbox(
                    &out,
                    population,
                    max_iterations,
                    only.as_deref(),
                    seat_kernel_draws,
                    overrides
                )?
            );
        }
        Command::Experiment(ExperimentCommand::Encoders {
            out,
            population,
            max_iterations,
            only,
        }) => {
            print!(
                "{}",
                crate::research::encoders::run(&out, population, max_iterations, only.as_deref())?
            );
        }
        Command::Experiment(ExperimentCommand::Defaults {
            out,
            targets,
            population,
            target_looks,
            preset,
            decoys_at_target_pupil,
            decoy_focus,
            leak_learned_reader,
            no_hint,
            security,
            target_focus,
            target_pupil,
            draws,
            wide_pupils,
            font,
            two_lines,
            decoys,
            decoy_weight,
            leak_weight,
            near_pupil_decoys,
            sub_rays,
            target_margin,
            adaptive_rounds,
            seed,
        }) => {
            let d = eyekey_core::encoding::pipeline::EncodeOptions::default();
            let options = eyekey_core::encoding::pipeline::EncodeOptions {
                decoys_at_target_pupil,
                decoy_focus,
                leak_learned_reader,
                population_decoys: decoys.unwrap_or(d.population_decoys),
                decoy_weight: decoy_weight.or(d.decoy_weight),
                leak_weight: leak_weight.unwrap_or(d.leak_weight),
                near_pupil_decoys: near_pupil_decoys.unwrap_or(d.near_pupil_decoys),
                sub_rays: sub_rays.unwrap_or(d.sub_rays),
                target_margin: target_margin.unwrap_or(d.target_margin),
                adaptive_rounds: adaptive_rounds.unwrap_or(d.adaptive_rounds),
                seed: Some(seed.unwrap_or(crate::research::EXPERIMENT_SEED)),
                security,
                target_focus_d: target_focus,
                target_pupil_mm: target_pupil,
                draws,
                ..d
            };
            let documents = match (font, two_lines) {
                (None, false) => crate::research::defaults::Documents::PinSlips,
                (Some(font), lines) => crate::research::defaults::Documents::InFont { font, lines },
                (None, true) => anyhow::bail!("--two-lines needs --font"),
            };
            let setup = crate::research::defaults::Setup {
                targets,
                population,
                target_looks,
                hint: !no_hint,
                wide_pupils,
                documents,
            };
            print!("{}", crate::research::defaults::run(&out, &setup, &preset, options)?);
        }
        Command::Experiment(ExperimentCommand::ReaderViews {
            out,
            preset,
            encodings,
            first,
            people,
            security,
            decoy_focus,
        }) => {
            let setup = crate::research::reader::Setup {
                preset,
                encodings,
                people,
                first,
            };
            let options = eyekey_core::encoding::pipeline::EncodeOptions {
                security,
                decoy_focus,
                ..Default::default()
            };
            println!("{}", crate::research::reader::run(&out, &setup, options)?);
        }
        Command::Experiment(ExperimentCommand::Secure { out, population }) => {
            print!("{}", crate::research::experiment::secure(&out, population)?);
        }
        Command::Experiment(ExperimentCommand::Wave { out, preset, fourier }) => {
            let display = DisplayGeometry::preset(&preset)?;
            print!(
                "{}",
                crate::research::wave::run(&out.join(&preset), &display, &preset, fourier)?
            );
        }
        Command::Experiment(ExperimentCommand::Calibrate { out, count, seed }) => {
            print!(
                "{}",
                crate::research::calibration::calibration_views(&out, count, seed)?
            );
            println!("wrote {count} views, views.csv and calibration.md to {}", out.display());
        }
    }
    Ok(())
}

fn example_profile(a: &ExampleProfileArgs) -> Result<VisionProfile> {
    if !(2.0..=9.0).contains(&a.pupil) {
        bail!("--pupil must be within 2..=9 mm, got {}", a.pupil);
    }
    if let Some(seed) = a.population_seed {
        let p = eyekey_core::physics::population::sample_population(1, seed, Default::default()).remove(0);
        p.validate()?;
        return Ok(p);
    }
    let mut p = VisionProfile {
        pupil_diameter_mm: a.pupil,
        ..VisionProfile::perfect()
    };
    if a.sphere.is_some() || a.cylinder.is_some() {
        let rx = Prescription {
            sphere_d: a.sphere.unwrap_or(0.0),
            cylinder_d: a.cylinder.unwrap_or(0.0),
            axis_deg: a.axis.unwrap_or(0.0),
        };
        rx.validate()?;
        // The refractive error goes into the Zernike terms directly, as an aberrometer would report it.
        let z = ZernikeCoefficients::from_prescription(&rx, a.pupil);
        for j in 3..=5 {
            p.zernike_um[j] = z.get(j);
        }
    }
    p.validate()?;
    Ok(p)
}

fn simulate(a: &SimulateArgs) -> Result<()> {
    let display = read_display(&a.display)?;
    let profile = read_profile(&a.profile)?;
    let options = TransportOptions {
        sub_rays: a.sub_rays,
        retina_oversample: a.oversample,
        ..Default::default()
    };
    let eye = EyePosition {
        x_mm: a.eye_x,
        y_mm: a.eye_y,
        dz_mm: a.eye_z,
    };
    let l = match (&a.image, &a.frames) {
        (Some(img), _) => plain_light_field_for_image(&display, &imaging::load_image(img)?),
        (None, Some(bundle)) => {
            let (manifest, l) = eyekey_core::bundle::read_bundle(bundle)?;
            if manifest.display != display {
                bail!(
                    "bundle {} was made for a different display than {} (holes {}×{}, views {}×{} vs {}×{}, {}×{})",
                    bundle.display(),
                    a.display.display(),
                    manifest.display.holes_x,
                    manifest.display.holes_y,
                    manifest.display.views_u,
                    manifest.display.views_v,
                    display.holes_x,
                    display.holes_y,
                    display.views_u,
                    display.views_v
                );
            }
            l
        }
        (None, None) => bail!("give --image or --frames"),
    };
    let cache = TransportCache::disabled();
    let observer = Observer::new(&display, &profile, eye, &options, a.optics, &cache)?;
    let picture = observer.picture(&observer.view(&l));
    let transports = observer.transports;
    imaging::save_rgb_png(&picture, &a.out)?;
    let (traced, entered): (u64, u64) = transports.iter().fold((0, 0), |(t, e), tr| {
        (t + tr.stats.sub_rays_traced, e + tr.stats.sub_rays_in_pupil)
    });
    eprintln!(
        "wrote {} ({}×{} retinal pixels; {:.1} % of traced rays entered the pupil)",
        a.out.display(),
        transports[0].grid.width,
        transports[0].grid.height,
        100.0 * entered as f64 / traced.max(1) as f64
    );
    Ok(())
}

/// A progress bar on a terminal, nothing otherwise.
fn progress_bar(label: &str) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {percent:>3}% {elapsed_precise}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(label.to_string());
    bar
}

fn encode(a: &EncodeArgs) -> Result<()> {
    use eyekey_core::encoding::pipeline::{EncodeOptions, JobSpec};
    if a.out.exists() {
        bail!("--out {} already exists; choose a new directory", a.out.display());
    }
    let display = read_display(&a.display)?;
    if let Some(w) = eyekey_core::physics::resolvability::Resolvability::of(&display).warning() {
        eprintln!("warning: {w} (see `eyekey display check`)");
    }
    let target = read_profile(&a.target)?;
    let observers = a.observer.iter().map(|p| read_profile(p)).collect::<Result<Vec<_>>>()?;
    let document = imaging::load_image(&a.document)?;
    let decoy = a.decoy.as_deref().map(imaging::load_image).transpose()?;
    let d = EncodeOptions::default();
    let options = EncodeOptions {
        method: a.method,
        optics: a.optics,
        ablation: a.ablation,
        population_decoys: a.population_decoys.unwrap_or(d.population_decoys),
        near_pupil_decoys: a.near_pupil_decoys.unwrap_or(d.near_pupil_decoys),
        near_pupil_ring_mm: a.near_pupil_ring.unwrap_or(d.near_pupil_ring_mm),
        target_margin: a.target_margin.unwrap_or(d.target_margin),
        decoy: match (a.decoy_kind, &decoy) {
            (Some(kind), _) => kind,
            (None, Some(_)) => DecoyKind::Image,
            (None, None) => d.decoy,
        },
        decoy_weight: a.decoy_weight.or(d.decoy_weight),
        leak_weight: a.leak_weight.unwrap_or(d.leak_weight),
        ensure_target_reads: !a.no_target_guard,
        seed: a.seed,
        sub_rays: a.sub_rays.unwrap_or(d.sub_rays),
        max_iterations: a.max_iterations.unwrap_or(d.max_iterations),
        tolerance: a.tolerance.unwrap_or(d.tolerance),
        lambda_w: a.lambda_w.unwrap_or(d.lambda_w),
        lambda_c: a.lambda_c.unwrap_or(d.lambda_c),
        evaluation_population: 0,
        head_radius_mm: a.head_radius.unwrap_or(d.head_radius_mm),
        head_weight: a.head_weight.unwrap_or(d.head_weight),
        adaptive_rounds: a.adaptive_rounds.unwrap_or(d.adaptive_rounds),
        camera_decoys: a.camera_decoys || d.camera_decoys,
        camera_decoy_ring_mm: a.camera_decoy_ring.unwrap_or(d.camera_decoy_ring_mm),
        document_text: a.hint.hint(),
        security: a.security,
        target_focus_d: a.target_focus.clone(),
        target_pupil_mm: a.target_pupil.clone(),
        ..d.clone()
    };
    if options.decoy == DecoyKind::Image && decoy.is_none() {
        bail!("--decoy-kind image needs --decoy IMAGE");
    }
    let spec = JobSpec {
        display,
        target,
        target_label: a.target.display().to_string(),
        observers,
        document,
        decoy,
        options,
    };
    let bar = progress_bar("encoding");
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let started = std::time::Instant::now();
    let cache = TransportCache::default();
    let encoded =
        eyekey_core::encoding::pipeline::encode(&spec, &cache, &|p| bar.set_position((p * 1000.0) as u64), &cancel)?;
    eyekey_core::encoding::pipeline::write_outputs(&spec, &encoded, &a.out, false, &cache, &|_| {}, &cancel)?;
    bar.finish_and_clear();
    if let Some(reading) = &encoded.solver.target_reading {
        eprintln!("target {}", reading.describe());
    }
    let o = &spec.options;
    eprintln!(
        "security {}: the target was asked to read in {} states besides its profile's (focus {:?} D, pupil {:?} mm; \
         a pupil the profile was not measured over is not tried); `eyekey evaluate` says who else reads",
        format!("{:?}", o.security).to_lowercase(),
        eyekey_core::encoding::pipeline::target_states(&spec).len(),
        o.focus_states_d(),
        o.pupil_states_mm(),
    );
    eprintln!(
        "wrote {} in {:.1} s (solver: {} iterations, {}; {} seed in {}, beside the bundle and not listed in its manifest: copy only the manifest's files to a display)",
        a.out.display(),
        started.elapsed().as_secs_f64(),
        encoded.solver.iterations,
        encoded.solver.termination,
        if a.seed.is_some() { "the given" } else { "a fresh" },
        a.out.join(eyekey_core::encoding::pipeline::ENCODING_FILE).display()
    );
    Ok(())
}

fn evaluate(a: &EvaluateArgs) -> Result<()> {
    use eyekey_core::evaluation::EvaluationOptions;
    let (manifest, l) = eyekey_core::bundle::read_bundle(&a.bundle)?;
    let target = read_profile(&a.target)?;
    let document = imaging::load_image(&a.document)?;
    let observers = a
        .observer
        .iter()
        .map(|p| Ok((p.display().to_string(), read_profile(p)?)))
        .collect::<Result<Vec<_>>>()?;
    if !(0.0..=1.0).contains(&a.threshold) {
        bail!("--threshold must be within 0..=1, got {}", a.threshold);
    }
    if a.population > 2000 {
        bail!("--population must be at most 2000, got {}", a.population);
    }
    let document_text = match a.hint.hint() {
        Some(hint) => Some(hint.resolve(&document).context("--text")?),
        None => None,
    };
    let options = EvaluationOptions {
        population: a.population,
        seed: a.seed,
        threshold: a.threshold,
        optics: a.optics,
        document_text,
        ..Default::default()
    };
    let bar = progress_bar("evaluating");
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let ev = eyekey_core::evaluation::evaluate(
        &manifest.display,
        &l,
        &document,
        eyekey_core::encoding::pipeline::OBJECTIVE_LEVEL,
        &target,
        &observers,
        &options,
        &TransportCache::default(),
        &|p| bar.set_position((p * 1000.0) as u64),
        &cancel,
    )?;
    bar.finish_and_clear();
    eyekey_core::encoding::pipeline::write_evaluation(&ev, &a.out)?;
    let r = &ev.report;
    println!(
        "target: {}; legibility {:.2}, PSNR {:.1} dB, SSIM {:.2}",
        r.target_reading.describe(),
        r.target.legibility,
        r.target.psnr_db,
        r.target.ssim
    );
    for o in &r.observers {
        println!(
            "{}: legibility {:.2}{}{}",
            o.label,
            o.legibility,
            o.focus_d.map_or(String::new(), |f| format!(" at focus {f:+.2} D")),
            if o.readable { " (READS)" } else { "" }
        );
    }
    if let Some(p) = &r.population {
        println!(
            "population: {}/{} can read, {} of them at their own focus (median legibility {:.2}, 95th percentile \
             {:.2}, max {:.2})",
            p.readable_count, p.count, p.readable_at_own_focus, p.median_legibility, p.p95_legibility, p.max_legibility
        );
    }
    match &r.learned_reader {
        Some(made) => println!("learned reader applied ({made})"),
        None => println!("no learned reader was trained on this document's layout; none was applied"),
    }
    if let Some(c) = &r.camera {
        println!(
            "camera attacker best: {} legibility {:.2}",
            c.best.label, c.best.legibility
        );
    }
    if let Some(k) = &r.key_sensitivity {
        println!(
            "key: optical radius {:.3} µm ({:.1} bits), spectral radius {:.2} SD ({:.1} bits), empirical ≥ {:.1} bits",
            k.optical_radius_um, k.optical_bits, k.spectral_radius_sd, k.spectral_bits, k.empirical_bits
        );
    }
    println!("wrote {}", a.out.join("report.json").display());
    Ok(())
}

/// Structured logs on stderr; `RUST_LOG` filters (default `info`), `EYEKEY_LOG_FORMAT=json` for JSON lines.
fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = if std::env::var("EYEKEY_LOG_FORMAT").as_deref() == Ok("json") {
        builder.json().try_init()
    } else {
        builder.try_init()
    };
}

/// Prints a line on stdout; a reader that went away (`eyekey example display | head`) is not an error.
/// `eyekey display check`: the resolvability table, or its JSON.
fn display_check(path: &Path, json: bool) -> Result<()> {
    let display = read_display(path)?;
    let r = eyekey_core::physics::resolvability::Resolvability::of(&display);
    if json {
        return print_stdout(&(serde_json::to_string_pretty(&r)? + "\n"));
    }
    let mut text = format!(
        "{} display, aperture {:.3} mm, views {}×{}, viewing distance {} mm\n\n\
         | band | wavelength nm | view spacing mm | view spread mm | resolvability M | views resolved 4 mm | 6 mm |\n\
         | --- | --- | --- | --- | --- | --- | --- |\n",
        display.aperture.as_str(),
        display.hole_diameter_mm,
        display.views_u,
        display.views_v,
        display.viewing_distance_mm
    );
    for (n, b) in r.bands.iter().enumerate() {
        text.push_str(&format!(
            "| {n} | {:.1} | {:.3} | {:.3} | {:.2} | {} | {} |\n",
            b.wavelength_nm,
            b.view_spacing_mm,
            b.view_spread_mm,
            b.resolvability,
            b.views_resolved.mm4,
            b.views_resolved.mm6
        ));
    }
    if let Some(w) = r.warning() {
        text.push_str(&format!("\nwarning: {w}\n"));
    }
    print_stdout(&text)
}

fn print_stdout(text: &str) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|_| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_args(args: &[&str]) -> Result<()> {
        run(Cli::try_parse_from(
            std::iter::once("eyekey").chain(args.iter().copied()),
        )?)
    }

    /// The README's offline example, as the README runs it but for 120 solver iterations instead of 300 and with a
    /// fixed seed (the README's draws a fresh one, as every encode does): the
    /// target must read the frames `encode` writes, by the judge without the text (legibility at the reads bar)
    /// and by the known-font attacker with it, and `evaluate` must say so.
    #[test]
    fn the_readmes_offline_example_gives_frames_its_target_reads() {
        let dir = tempfile::tempdir().unwrap();
        let path = |name: &str| dir.path().join(name).display().to_string();
        std::fs::write(
            path("display.json"),
            serde_json::to_vec(&DisplayGeometry::preset("lenslet").unwrap()).unwrap(),
        )
        .unwrap();
        let me = eyekey_core::physics::population::sample_population(1, 11, Default::default()).remove(0);
        std::fs::write(path("me.json"), serde_json::to_vec(&me).unwrap()).unwrap();
        run_args(&[
            "example",
            "document",
            "--text",
            "PIN",
            "--text",
            "4821",
            "--width",
            "192",
            "--height",
            "192",
            "--scale",
            "6",
            "--out",
            &path("pin.png"),
        ])
        .unwrap();
        let (display, me_json, pin, bundle) = (path("display.json"), path("me.json"), path("pin.png"), path("bundle"));
        run_args(&[
            "encode",
            "--display",
            &display,
            "--target",
            &me_json,
            "--document",
            &pin,
            "--population-decoys",
            "12",
            "--decoy-weight",
            "0.2",
            "--adaptive-rounds",
            "2",
            "--camera-decoys",
            "--max-iterations",
            "120",
            "--seed",
            "7",
            "--out",
            &bundle,
        ])
        .expect("the target reads, or encode fails with target_cannot_read");
        let record: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("bundle/encoding.json")).unwrap()).unwrap();
        let reading = &record["solver"]["target_reading"];
        assert_eq!(reading["judge"], "legibility", "{reading}");
        assert_eq!(reading["reads"], true, "{reading}");
        for (out, hint) in [("plain", false), ("hinted", true)] {
            let out = path(out);
            let mut args = vec![
                "evaluate",
                "--bundle",
                &bundle,
                "--target",
                &me_json,
                "--document",
                &pin,
                "--population",
                "0",
                "--out",
                &out,
            ];
            if hint {
                args.extend(["--text", "PIN", "--text", "4821", "--text-scale", "6"]);
            }
            run_args(&args).unwrap();
            let report: serde_json::Value =
                serde_json::from_slice(&std::fs::read(format!("{out}/report.json")).unwrap()).unwrap();
            let t = &report["target_reading"];
            assert_eq!(t["reads"], true, "{out}: {t}");
            assert_eq!(t["judge"], if hint { "known_font" } else { "legibility" }, "{t}");
            if hint {
                assert_eq!(report["target"]["known_font"]["text"], "4821", "{report}");
            }
        }
    }
}
