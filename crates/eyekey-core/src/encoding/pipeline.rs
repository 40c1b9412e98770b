//! The whole offline pipeline for one job: transport operators → solver → frame bundle → evaluation.
//!
//! Both the CLI (`eyekey encode`) and the service's workers call [`run_job`]; it is synchronous, runs its
//! heavy work on the rayon pool, reports progress in 0..=1 and checks `cancel` between solver iterations.

pub use super::job::*;
pub use super::options::*;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use crate::physics::profile::VisionProfile;

/// The light field and what the solver did.
pub struct Encoded {
    /// Band-interleaved light field, `l[p·N + n]`, in [0, L_max].
    pub light_field: Vec<f32>,
    /// The solver's result (without the light field).
    pub solver: serde_json::Value,
}

/// Encodes a job's document into a light field (no files written).
pub fn encode(spec: &JobSpec, progress: &(dyn Fn(f64) + Sync), cancel: &AtomicBool) -> Result<Encoded, PipelineError> {
    use crate::encoding::objectives::{noise_decoy, DiffMaxObjective, MultiplexObjective, Term, TiedViews};
    use crate::encoding::solver::{minimise, Objective, SolverOptions};
    use crate::physics::observer::Observer;
    use crate::physics::transport::{EyePosition, TransportOptions};

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
    let internal = |e: crate::physics::observer::ObserverError| PipelineError::Invalid(e.to_string());
    let target = Observer::new(d, &spec.target, EyePosition::default(), &target_opts).map_err(internal)?;
    progress(0.05);

    // Everybody who must NOT read: given observers, then decoys sampled from the population.
    let mut others_profiles = spec.observers.clone();
    if !matches!(o.method, Method::Diffmax) {
        others_profiles.extend(crate::physics::population::sample_population(
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
            let rx = crate::physics::zernike::Prescription {
                sphere_d: focus,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            };
            let lens = crate::physics::zernike::ZernikeCoefficients::from_prescription(&rx, 6.0);
            let tr = crate::physics::transport::TransportCache::global()
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
    let plain = crate::physics::observer::plain_light_field_for_image(d, &spec.document);
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
    let reference = crate::evaluation::Reference::new(
        &spec.document,
        g.width,
        g.height,
        OBJECTIVE_LEVEL,
        crate::evaluation::DEFAULT_THRESHOLD,
    );
    for round in 0..=rounds {
        let done_before = iterations as f64;
        let mut report = |p: crate::encoding::solver::Progress| {
            progress(0.15 + 0.7 * (done_before + p.iteration as f64) / total_its)
        };
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
        if result.termination == crate::encoding::solver::Termination::Cancelled {
            return Err(PipelineError::Cancelled);
        }
        if result.termination == crate::encoding::solver::Termination::NumericalFailure {
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
        let candidates = crate::physics::population::sample_population(
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

impl crate::encoding::solver::Objective for DummyDim {
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
    use crate::evaluation::{evaluate, EvaluationOptions};
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
                crate::evaluation::EvaluationError::Cancelled => PipelineError::Cancelled,
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
pub fn write_evaluation(evaluation: &crate::evaluation::Evaluation, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
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
