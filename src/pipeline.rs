//! The whole offline pipeline for one job: transport operators → solver → frame bundle → evaluation.
//!
//! Both the CLI (`eyekey encode`) and the service's workers call [`run_job`]; it is synchronous, runs its
//! heavy work on the rayon pool, reports progress in 0..=1 and checks `cancel` between solver iterations.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use crate::display::DisplayGeometry;
use crate::optics::profile::VisionProfile;

/// Which encoder to run (paper §6).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
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

/// Options of one encode; every field has a sensible default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EncodeOptions {
    /// The encoder.
    pub method: Method,
    /// Optional ablation.
    pub ablation: Option<Ablation>,
    /// Decoy observers sampled from the population, each shown a decoy (0 = only the given observers).
    pub population_decoys: u32,
    /// What decoy observers see.
    pub decoy: DecoyKind,
    /// Weight of each decoy observer's term relative to the target's (1.0).
    pub decoy_weight: f64,
    /// Seed for population sampling, jitter and noise decoys.
    pub seed: u64,
    /// Sub-rays traced per light-field sample (S).
    pub sub_rays: u32,
    /// Solver iteration cap.
    pub max_iterations: u32,
    /// Relative objective change below which the solver stops.
    pub tolerance: f64,
    /// λ_W of Eq. 16 (difference maximisation), relative to the data term.
    pub lambda_w: f64,
    /// λ_c of Eq. 16 (difference maximisation), relative to the data term.
    pub lambda_c: f64,
    /// People sampled from the population for the evaluation report (0 skips it).
    pub evaluation_population: u32,
    /// Head-movement robustness: besides the design position, the target must also read from four eye
    /// positions this far off axis (mm; 0 = only the design position). Stacked observers, as in the
    /// 2014 eyeglasses-free display.
    pub head_radius_mm: f64,
    /// Adaptive decoy rounds: after each solve, sample `adaptive_candidates` fresh people and add up to
    /// `adaptive_per_round` of those who can still read as decoys, then solve again (0 = off).
    pub adaptive_rounds: u32,
    /// People sampled per adaptive round.
    pub adaptive_candidates: u32,
    /// Decoys added per adaptive round at most.
    pub adaptive_per_round: u32,
    /// Camera decoys: an ideal 6 mm lens focused at −0.5 D and +0.5 D behind a filter passing one projector band
    /// (the evaluation's strongest attacker), each shown a noise mask.
    pub camera_decoys: bool,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        Self {
            method: Method::Multiplex,
            ablation: None,
            population_decoys: 6,
            decoy: DecoyKind::Noise,
            decoy_weight: 1.0,
            seed: 1,
            sub_rays: 16,
            max_iterations: 300,
            tolerance: 1e-5,
            lambda_w: 0.05,
            lambda_c: 0.05,
            evaluation_population: 20,
            head_radius_mm: 0.0,
            adaptive_rounds: 0,
            adaptive_candidates: 24,
            adaptive_per_round: 4,
            camera_decoys: false,
        }
    }
}

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

impl EncodeOptions {
    /// Checks every option's range; errors name the field.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let bad = |field: &str, why: String| Err(PipelineError::Invalid(format!("options.{field}: {why}")));
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
        if self.population_decoys > 64 {
            return bad(
                "population_decoys",
                format!("at most 64, got {}", self.population_decoys),
            );
        }
        if !(self.decoy_weight.is_finite() && (0.0..=100.0).contains(&self.decoy_weight)) {
            return bad(
                "decoy_weight",
                format!("must be within 0..=100, got {}", self.decoy_weight),
            );
        }
        for (name, v) in [("lambda_w", self.lambda_w), ("lambda_c", self.lambda_c)] {
            if !(v.is_finite() && (0.0..=100.0).contains(&v)) {
                return bad(name, format!("must be within 0..=100, got {v}"));
            }
        }
        if !(self.head_radius_mm.is_finite() && (0.0..=20.0).contains(&self.head_radius_mm)) {
            return bad(
                "head_radius_mm",
                format!("must be within 0..=20 mm, got {}", self.head_radius_mm),
            );
        }
        if self.adaptive_rounds > 5 || self.adaptive_candidates > 200 || self.adaptive_per_round > 16 {
            return bad(
                "adaptive_rounds",
                "at most 5 rounds of at most 200 candidates adding at most 16 decoys each".to_string(),
            );
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

fn aspect_matches(img: &image::RgbImage, display: &DisplayGeometry) -> bool {
    let a = img.width() as f64 / img.height() as f64;
    let b = display.holes_x as f64 / display.holes_y as f64;
    (a / b - 1.0).abs() <= 0.05
}

/// The light field and what the solver did.
pub struct Encoded {
    /// Band-interleaved light field, `l[p·N + n]`, in [0, L_max].
    pub light_field: Vec<f32>,
    /// The solver's result (without the light field).
    pub solver: serde_json::Value,
}

/// Encodes a job's document into a light field (no files written).
pub fn encode(spec: &JobSpec, progress: &(dyn Fn(f64) + Sync), cancel: &AtomicBool) -> Result<Encoded, PipelineError> {
    use crate::encode::{noise_decoy, DiffMaxObjective, MultiplexObjective, Term, TiedViews};
    use crate::observer::Observer;
    use crate::solve::{minimise, Objective, SolverOptions};
    use crate::transport::{EyePosition, TransportOptions};

    let o = &spec.options;
    o.validate()?;
    let d = &spec.display;
    d.validate()
        .map_err(|e| PipelineError::Invalid(format!("display: {e}")))?;
    spec.target
        .validate()
        .map_err(|e| PipelineError::Invalid(format!("target profile: {e}")))?;
    for (k, p) in spec.observers.iter().enumerate() {
        p.validate()
            .map_err(|e| PipelineError::Invalid(format!("observers[{k}]: {e}")))?;
    }
    if !aspect_matches(&spec.document, d) {
        return Err(PipelineError::Invalid(format!(
            "document is {}×{} pixels but the display is {}×{} holes: aspect ratios differ by more than 5 %",
            spec.document.width(),
            spec.document.height(),
            d.holes_x,
            d.holes_y
        )));
    }
    if let Some(decoy) = &spec.decoy {
        if !aspect_matches(decoy, d) {
            return Err(PipelineError::Invalid(format!(
                "decoy is {}×{} pixels; its aspect ratio must match the display's {}×{} holes",
                decoy.width(),
                decoy.height(),
                d.holes_x,
                d.holes_y
            )));
        }
    }
    let diffmax = matches!(o.method, Method::Diffmax | Method::Combined);
    let base = TransportOptions {
        sub_rays: o.sub_rays,
        seed: o.seed,
        retina_oversample: 1,
        derivative_terms: vec![],
    };
    let target_opts = TransportOptions {
        derivative_terms: if diffmax { DIFFMAX_TERMS.collect() } else { vec![] },
        ..base.clone()
    };
    let internal = |e: crate::observer::ObserverError| PipelineError::Invalid(e.to_string());
    let target = Observer::new(d, &spec.target, EyePosition::default(), &target_opts).map_err(internal)?;
    progress(0.05);

    // Everybody who must NOT read: given observers, then decoys sampled from the population.
    let mut others_profiles = spec.observers.clone();
    if !matches!(o.method, Method::Diffmax) {
        others_profiles.extend(crate::population::sample_population(
            o.population_decoys as usize,
            o.seed.wrapping_add(1),
            Default::default(),
        ));
    } else {
        others_profiles.clear();
    }
    let mut others = Vec::with_capacity(others_profiles.len());
    for (k, p) in others_profiles.iter().enumerate() {
        if cancel.load(std::sync::atomic::Ordering::Relaxed) {
            return Err(PipelineError::Cancelled);
        }
        let mut obs = Observer::new(d, p, EyePosition::default(), &base).map_err(internal)?;
        if o.ablation == Some(Ablation::Optical) {
            // Optical only: the spectral key is taken away by giving everybody the target's cones.
            obs = Observer::with_coupling(obs.transport.clone(), target.coupling_f64.clone(), d.l_max);
        }
        others.push(obs);
        progress(0.05 + 0.1 * (k + 1) as f64 / others_profiles.len() as f64);
    }
    let g = target.transport.grid;
    let n_bands_all = d.n_bands();
    let target_obj = target.objective(&spec.document, OBJECTIVE_LEVEL);
    let energy: f64 = target_obj.iter().map(|v| (*v as f64).powi(2)).sum();
    // Stacked target observers at four eye positions on a ring of radius head_radius_mm, each asked for the
    // document with a quarter of the central weight.
    let mut moved = Vec::new();
    if o.head_radius_mm > 0.0 {
        let r = o.head_radius_mm;
        for (dx, dy) in [(r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)] {
            let eye = EyePosition {
                x_mm: dx,
                y_mm: dy,
                dz_mm: 0.0,
            };
            moved.push(Observer::new(d, &spec.target, eye, &base).map_err(internal)?);
        }
    }
    if o.camera_decoys && !matches!(o.method, Method::Diffmax) {
        for focus in [-0.5, 0.5] {
            let rx = crate::optics::zernike::Prescription {
                sphere_d: focus,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            };
            let lens = crate::optics::zernike::ZernikeCoefficients::from_prescription(&rx, 6.0);
            let tr = crate::transport::TransportCache::global()
                .get_or_build(d, &lens, EyePosition::default(), &base)
                .map_err(|e| PipelineError::Invalid(e.to_string()))?;
            for band in 0..n_bands_all {
                let c = (0..n_bands_all)
                    .map(|m| if m == band { [1.0; 3] } else { [0.0; 3] })
                    .collect();
                others.push(Observer::with_coupling(tr.clone(), c, d.l_max));
            }
        }
    }
    let decoy_for = |k: usize| match (o.decoy, &spec.decoy) {
        (DecoyKind::Grey, _) => image::RgbImage::from_pixel(g.width, g.height, image::Rgb([188, 188, 188])),
        (DecoyKind::Image, Some(img)) => img.clone(),
        _ => noise_decoy(g.width, g.height, 2, o.seed.wrapping_add(100 + k as u64)),
    };
    let mut decoy_objectives: Vec<Vec<f32>> = others
        .iter()
        .enumerate()
        .map(|(k, obs)| obs.objective(&decoy_for(k), OBJECTIVE_LEVEL))
        .collect();
    let solver_opts = SolverOptions {
        max_iterations: o.max_iterations,
        tolerance: o.tolerance,
        ..Default::default()
    };
    let rounds = if matches!(o.method, Method::Diffmax) {
        0
    } else {
        o.adaptive_rounds
    };
    let total_its = o.max_iterations as f64 * (rounds + 1) as f64;
    let l_max = d.l_max as f32;
    let tied = o.ablation == Some(Ablation::Spectral);
    // Warm start: the document shown plainly at the objective level.
    let plain = crate::observer::plain_light_field_for_image(d, &spec.document);
    let n = d.n_bands();
    let mut x: Vec<f32> = if tied {
        (0..(d.holes_x * d.holes_y) as usize * n)
            .map(|h| {
                let (hx, hy) = ((h / n) as u32 % d.holes_x, (h / n) as u32 / d.holes_x);
                plain[d.sample_index(hx, hy, 0, 0) * n + h % n] * OBJECTIVE_LEVEL as f32
            })
            .collect()
    } else {
        plain.iter().map(|v| v * OBJECTIVE_LEVEL as f32).collect()
    };
    let mut history = Vec::new();
    let (mut iterations, mut restarts, mut seconds) = (0u32, 0u32, 0.0f64);
    let mut last = None;
    let mut added_per_round = Vec::new();
    let reference = crate::evaluate::Reference::new(
        &spec.document,
        g.width,
        g.height,
        OBJECTIVE_LEVEL,
        crate::evaluate::DEFAULT_THRESHOLD,
    );
    for round in 0..=rounds {
        let done_before = iterations as f64;
        let mut report =
            |p: crate::solve::Progress| progress(0.15 + 0.7 * (done_before + p.iteration as f64) / total_its);
        let result = {
            let mut terms = vec![Term {
                observer: &target,
                objective: target_obj.clone(),
                weight: 1.0,
            }];
            for m in &moved {
                terms.push(Term {
                    observer: m,
                    objective: target_obj.clone(),
                    weight: 0.25,
                });
            }
            for (obs, obj) in others.iter().zip(&decoy_objectives) {
                terms.push(Term {
                    observer: obs,
                    objective: obj.clone(),
                    weight: o.decoy_weight,
                });
            }
            let data = MultiplexObjective::new(terms, n, energy, 1e-4);
            let dm;
            let objective: &dyn Objective = if diffmax {
                // Ablations take the other key's derivative term away: optical only keeps λ_W, spectral only λ_c.
                let lambda_w = if o.ablation == Some(Ablation::Spectral) {
                    0.0
                } else {
                    o.lambda_w
                };
                let lambda_c = if o.ablation == Some(Ablation::Optical) {
                    0.0
                } else {
                    o.lambda_c
                };
                dm = DiffMaxObjective::new(data, &target, lambda_w, lambda_c);
                &dm
            } else {
                &data
            };
            if tied {
                let t = TiedViews::new(objective, d);
                minimise(&t, x.clone(), 0.0, l_max, &solver_opts, &mut report, cancel)
            } else {
                minimise(objective, x.clone(), 0.0, l_max, &solver_opts, &mut report, cancel)
            }
        };
        if result.termination == crate::solve::Termination::Cancelled {
            return Err(PipelineError::Cancelled);
        }
        if result.termination == crate::solve::Termination::NumericalFailure {
            return Err(PipelineError::Internal(
                "the solver's objective became non-finite".into(),
            ));
        }
        iterations += result.iterations;
        restarts += result.restarts;
        seconds += result.seconds;
        history.extend_from_slice(&result.history);
        x = result.x.clone();
        last = Some(result);
        if round == rounds {
            break;
        }
        // Adaptive decoys: sample fresh candidates (a seed stream the evaluation never uses), and add as decoy
        // observers the ones who can still read, most legible first.
        let l_now = if tied {
            TiedViews::new(&DummyDim(x.len()), d).expand(&x)
        } else {
            x.clone()
        };
        let candidates = crate::population::sample_population(
            o.adaptive_candidates as usize,
            o.seed.wrapping_add(7_000 + 1_000 * round as u64),
            Default::default(),
        );
        let mut scored = Vec::new();
        for p in &candidates {
            if cancel.load(std::sync::atomic::Ordering::Relaxed) {
                return Err(PipelineError::Cancelled);
            }
            let mut obs = Observer::new(d, p, EyePosition::default(), &base).map_err(internal)?;
            if o.ablation == Some(Ablation::Optical) {
                obs = Observer::with_coupling(obs.transport.clone(), target.coupling_f64.clone(), d.l_max);
            }
            let legibility = reference.score_observer("candidate", &obs, &l_now).0.legibility;
            scored.push((legibility, obs));
        }
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut added = 0;
        for (legibility, obs) in scored.into_iter().take(o.adaptive_per_round as usize) {
            if legibility < 0.8 * reference.threshold {
                break;
            }
            let k = others.len();
            decoy_objectives.push(obs.objective(&decoy_for(k), OBJECTIVE_LEVEL));
            others.push(obs);
            added += 1;
        }
        added_per_round.push(added);
        if added == 0 {
            break;
        }
    }
    let result = last.expect("at least one round ran");
    let l = if tied {
        TiedViews::new(&DummyDim(x.len()), d).expand(&x)
    } else {
        x
    };
    progress(0.85);
    let solver = serde_json::json!({
        "algorithm": "FISTA with gradient restart, step 1/L (power iteration)",
        "iterations": iterations,
        "restarts": restarts,
        "termination": result.termination,
        "objective": result.objective,
        "objective_history": history,
        "lipschitz": result.lipschitz,
        "seconds": seconds,
        "observers": others.len() + 1 + moved.len(),
        "adaptive_decoys_added": added_per_round,
        "unknowns": l.len(),
    });
    Ok(Encoded { light_field: l, solver })
}

/// A stand-in objective used only to reach [`TiedViews::expand`], which needs no objective.
struct DummyDim(usize);

impl crate::solve::Objective for DummyDim {
    fn dim(&self) -> usize {
        self.0
    }
    fn value_and_gradient(&self, _: &[f32], grad: &mut [f32]) -> f64 {
        grad.iter_mut().for_each(|g| *g = 0.0);
        0.0
    }
}

/// Runs one job and writes its bundle (frames, barrier mask, manifest) and evaluation into `out_dir`.
pub fn run_job(
    spec: &JobSpec,
    out_dir: &Path,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &AtomicBool,
) -> Result<JobOutput, PipelineError> {
    let encoded = encode(spec, &|p| progress(0.8 * p), cancel)?;
    write_outputs(spec, &encoded, out_dir, true, &|p| progress(0.8 + 0.2 * p), cancel)
}

/// Evaluates an encoded light field (when `with_evaluation`), then writes its bundle into `out_dir` and the
/// evaluation beside it (report.json, views/).
pub fn write_outputs(
    spec: &JobSpec,
    encoded: &Encoded,
    out_dir: &Path,
    with_evaluation: bool,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &AtomicBool,
) -> Result<JobOutput, PipelineError> {
    use crate::evaluate::{evaluate, EvaluationOptions};
    let io = |e: std::io::Error| PipelineError::Internal(format!("writing {}: {e}", out_dir.display()));
    let document_sha256 = {
        use sha2::Digest;
        hex::encode(sha2::Sha256::digest(spec.document.as_raw()))
    };
    let meta = crate::bundle::BundleMeta {
        profile_label: spec.target_label.clone(),
        document_sha256,
        encoder: serde_json::to_value(&spec.options).map_err(|e| PipelineError::Internal(e.to_string()))?,
        solver: encoded.solver.clone(),
    };
    // Evaluate first, so a cancelled or failed evaluation leaves no bundle behind.
    let eval_opts = EvaluationOptions {
        population: spec.options.evaluation_population,
        seed: spec.options.seed.wrapping_add(20_000),
        sub_rays: spec.options.sub_rays,
        ..Default::default()
    };
    let labelled: Vec<(String, VisionProfile)> = spec
        .observers
        .iter()
        .enumerate()
        .map(|(k, p)| (format!("observer_{k}"), p.clone()))
        .collect();
    let evaluation = if !with_evaluation {
        None
    } else {
        Some(
            evaluate(
                &spec.display,
                &encoded.light_field,
                &spec.document,
                OBJECTIVE_LEVEL,
                &spec.target,
                &labelled,
                &eval_opts,
                &|p| progress(0.9 * p),
                cancel,
            )
            .map_err(|e| match e {
                crate::evaluate::EvaluationError::Cancelled => PipelineError::Cancelled,
                other => PipelineError::Internal(other.to_string()),
            })?,
        )
    };
    let manifest = crate::bundle::write_bundle(out_dir, &spec.display, &encoded.light_field, &meta, &[], 4)
        .map_err(|e| PipelineError::Internal(e.to_string()))?;
    // Operator-only outputs live beside the bundle and are never listed in its manifest.
    let mut files = Vec::new();
    let mut report = serde_json::Value::Null;
    if let Some(evaluation) = &evaluation {
        report = serde_json::to_value(&evaluation.report).map_err(|e| PipelineError::Internal(e.to_string()))?;
        files.extend(write_evaluation(evaluation, out_dir).map_err(io)?);
    }
    for f in &manifest.files {
        files.push(out_dir.join(&f.name));
    }
    files.push(out_dir.join(crate::bundle::MANIFEST_FILE));
    progress(1.0);
    Ok(JobOutput {
        manifest: serde_json::to_value(&manifest).map_err(|e| PipelineError::Internal(e.to_string()))?,
        evaluation: report,
        files,
    })
}

/// Writes `report.json` and `views/*.png` of an evaluation into `dir`; returns the paths written.
pub fn write_evaluation(evaluation: &crate::evaluate::Evaluation, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    std::fs::create_dir_all(dir)?;
    let report_path = dir.join("report.json");
    let text = serde_json::to_vec_pretty(&evaluation.report).map_err(std::io::Error::other)?;
    std::fs::write(&report_path, text)?;
    files.push(report_path);
    let views = dir.join("views");
    std::fs::create_dir_all(&views)?;
    for (name, pic) in &evaluation.pictures {
        let path = views.join(name);
        crate::imaging::save_rgb_png(pic, &path).map_err(std::io::Error::other)?;
        files.push(path);
    }
    Ok(files)
}
