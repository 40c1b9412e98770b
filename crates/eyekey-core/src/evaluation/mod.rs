//! Is it actually secret? Fidelity for the target and readability for everybody else (DESIGN §4).
//!
//! Readability is judged contrast-invariantly: an attacker stretches contrast and denoises, so the score is
//! the best |normalised cross-correlation| between the document's luminance and the view's luminance after
//! Gaussian denoising at a few strengths ([`legibility`]). Its threshold is calibrated against OCR
//! (see `docs/legibility-calibration.md`). Fidelity is PSNR and SSIM (Wang et al. 2004) against the objective.
//!
//! Every simulated view here uses a sub-ray jitter seed different from the encoder's, so an encoding cannot
//! look good merely by fitting the sampling pattern of its own transport operator.

mod attackers;
mod contact_sheet;
mod key_sensitivity;
mod metrics;
mod options;
mod reference;
mod report;

use attackers::*;
pub use contact_sheet::contact_sheet;
use key_sensitivity::*;
pub use metrics::*;
pub use options::EvaluationOptions;
pub use reference::Reference;
pub use report::*;

use std::sync::atomic::{AtomicBool, Ordering};

use image::{Rgb, RgbImage};

use crate::physics::display::DisplayGeometry;
use crate::physics::observer::Observer;
use crate::physics::population::{sample_population, SamplingScope};
use crate::physics::profile::VisionProfile;
use crate::physics::spectral::coupling;
use crate::physics::transport::{EyePosition, TransportOptions};
use crate::physics::zernike::ZernikeCoefficients;

/// Evaluates light field `l`: the target, the given observers, a population sample, a camera attacker, key
/// sensitivity and head movement. `progress` receives 0..=1.
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    display: &DisplayGeometry,
    l: &[f32],
    document: &RgbImage,
    level: f64,
    target: &VisionProfile,
    observers: &[(String, VisionProfile)],
    options: &EvaluationOptions,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &AtomicBool,
) -> Result<Evaluation, EvaluationError> {
    let topts = TransportOptions {
        sub_rays: options.sub_rays,
        seed: options.seed ^ 0xE7A1,
        ..Default::default()
    };
    let check = || {
        if cancel.load(Ordering::Relaxed) {
            Err(EvaluationError::Cancelled)
        } else {
            Ok(())
        }
    };
    let t_obs = Observer::new(display, target, EyePosition::default(), &topts)?;
    let g = t_obs.transport.grid;
    let reference = Reference::new(document, g.width, g.height, level, options.threshold);
    let mut pictures = Vec::new();
    let objective = t_obs.objective(document, level);
    pictures.push(("objective.png".to_string(), t_obs.picture(&objective)));
    let (target_score, pic) = reference.score_observer("target", &t_obs, l);
    pictures.push(("target.png".to_string(), pic));

    let mut observer_scores = Vec::new();
    for (k, (label, p)) in observers.iter().enumerate() {
        check()?;
        let o = Observer::new(display, p, EyePosition::default(), &topts)?;
        let (s, pic) = reference.score_observer(label, &o, l);
        observer_scores.push(s);
        pictures.push((format!("observer_{k}.png"), pic));
    }
    progress(0.1);

    // Population: people sampled from published statistics, each at the design eye position (the worst case:
    // a bystander who takes the target's seat).
    let population = if options.population > 0 {
        let people = sample_population(options.population as usize, options.seed, SamplingScope::default());
        let mut scores = Vec::with_capacity(people.len());
        let mut kept: Vec<(usize, RgbImage)> = Vec::new();
        for (k, p) in people.iter().enumerate() {
            check()?;
            let o = Observer::new(display, p, EyePosition::default(), &topts)?;
            let (s, pic) = reference.score_observer(&format!("person_{k}"), &o, l);
            if (k as u32) < options.saved_population_views {
                kept.push((k, pic.clone()));
            }
            let worst_so_far = scores.iter().all(|w: &ViewScore| s.legibility > w.legibility);
            if worst_so_far {
                kept.retain(|(i, _)| *i != usize::MAX);
                kept.push((usize::MAX, pic));
            }
            scores.push(s);
            progress(0.1 + 0.5 * (k + 1) as f64 / people.len() as f64);
        }
        for (k, pic) in kept {
            let name = if k == usize::MAX {
                "population_worst.png".to_string()
            } else {
                format!("person_{k}.png")
            };
            pictures.push((name, pic));
        }
        let mut legs: Vec<f64> = scores.iter().map(|s| s.legibility).collect();
        legs.sort_by(|a, b| a.total_cmp(b));
        let readable = scores.iter().filter(|s| s.readable).count() as u32;
        Some(PopulationSummary {
            count: scores.len() as u32,
            readable_count: readable,
            readable_fraction: readable as f64 / scores.len().max(1) as f64,
            median_legibility: percentile(&legs, 0.5),
            p95_legibility: percentile(&legs, 0.95),
            max_legibility: legs.last().copied().unwrap_or(0.0),
            fraction_at_or_above: [0.2, 0.3, DEFAULT_THRESHOLD, 0.5, 0.6]
                .iter()
                .map(|&t| {
                    (
                        t,
                        legs.iter().filter(|v| **v >= t).count() as f64 / legs.len().max(1) as f64,
                    )
                })
                .collect(),
            people: scores,
        })
    } else {
        None
    };

    // Camera attacker: ideal optics, focus swept, several apertures, RGB sensor with and without a narrow
    // filter per projector band; each channel judged alone; its best case is reported.
    let camera = if !options.camera_focus_d.is_empty() && !options.camera_apertures_mm.is_empty() {
        let rgb = coupling(&display.projectors, &camera_rgb()).c;
        let mut tried = Vec::new();
        let mut best: Option<(ViewScore, RgbImage)> = None;
        for &aperture in &options.camera_apertures_mm {
            for &focus in &options.camera_focus_d {
                check()?;
                let w = ZernikeCoefficients::from_prescription(
                    &crate::physics::zernike::Prescription {
                        sphere_d: focus,
                        cylinder_d: 0.0,
                        axis_deg: 0.0,
                    },
                    aperture,
                );
                let tr = crate::physics::transport::TransportCache::global()
                    .get_or_build(display, &w, EyePosition::default(), &topts)
                    .map_err(crate::physics::observer::ObserverError::from)?;
                // Channel configurations: R, G, B of the sensor, then each band isolated by a filter.
                let mut configs: Vec<(String, Vec<[f64; 3]>)> = (0..3)
                    .map(|ch| {
                        let name = ["R", "G", "B"][ch];
                        (name.to_string(), rgb.iter().map(|c| [c[ch], c[ch], c[ch]]).collect())
                    })
                    .collect();
                for n in 0..display.n_bands() {
                    let sel = (0..display.n_bands())
                        .map(|m| if m == n { [1.0; 3] } else { [0.0; 3] })
                        .collect();
                    configs.push((format!("filter_band_{n}"), sel));
                }
                for (name, c) in configs {
                    let cam = Observer::with_coupling(tr.clone(), c, display.l_max);
                    let view = cam.view(l);
                    let lum: Vec<f32> = view.chunks_exact(3).map(|p| p[0]).collect();
                    let label = format!("camera f={focus:+.1}D aperture={aperture}mm {name}");
                    let s = reference.score(&label, &lum, cam.white[0]);
                    if best.as_ref().is_none_or(|(b, _)| s.legibility > b.legibility) {
                        // The attacker's picture: the channel stretched to its own range, shown in grey.
                        let (lo, hi) = lum
                            .iter()
                            .fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
                        let pic = RgbImage::from_fn(g.width, g.height, |x, y| {
                            let v = (lum[(y * g.width + x) as usize] - lo) / (hi - lo).max(1e-12);
                            let b = (v.clamp(0.0, 1.0) * 255.0) as u8;
                            Rgb([b, b, b])
                        });
                        best = Some((s.clone(), pic));
                    }
                    tried.push(s);
                }
            }
        }
        progress(0.75);
        best.map(|(b, pic)| {
            pictures.push(("camera_best.png".to_string(), pic));
            CameraSummary { best: b, tried }
        })
    } else {
        None
    };

    let key_sensitivity = if options.key_directions > 0 {
        check()?;
        Some(key_sensitivity(
            display, l, target, &reference, options, &topts, cancel,
        )?)
    } else {
        None
    };
    progress(0.9);

    let head_movement = if !options.head_offsets_mm.is_empty() {
        let mut worst = Vec::new();
        for &r in &options.head_offsets_mm {
            check()?;
            let mut w = f64::INFINITY;
            for (dx, dy) in [(r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)] {
                let o = Observer::new(
                    display,
                    target,
                    EyePosition {
                        x_mm: dx,
                        y_mm: dy,
                        dz_mm: 0.0,
                    },
                    &topts,
                )?;
                w = w.min(reference.score_observer("target moved", &o, l).0.legibility);
            }
            worst.push(w);
        }
        let mut radius = 0.0;
        if target_score.readable {
            for (r, w) in options.head_offsets_mm.iter().zip(&worst) {
                if *w >= options.threshold {
                    radius = *r;
                } else {
                    break;
                }
            }
        }
        Some(HeadMovement {
            offsets_mm: options.head_offsets_mm.clone(),
            worst_legibility: worst,
            readable_radius_mm: radius,
        })
    } else {
        None
    };
    progress(1.0);

    let mut report = Report {
        metric:
            "legibility = max over Gaussian denoising σ ∈ {0, 0.7, 1.5} px of |NCC(view luminance, document luminance)|"
                .into(),
        threshold: options.threshold,
        target: target_score,
        observers: observer_scores,
        population,
        camera,
        key_sensitivity,
        head_movement,
    };
    if let (Some(k), Some(p)) = (report.key_sensitivity.as_mut(), report.population.as_ref()) {
        k.empirical_bits = -(((p.readable_count + 1) as f64) / ((p.count + 1) as f64)).log2();
    }
    pictures.push(("contact_sheet.png".to_string(), contact_sheet(&report, &pictures)));
    Ok(Evaluation { report, pictures })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ncc_is_contrast_and_sign_invariant_in_legibility() {
        let doc: Vec<f32> = (0..400).map(|i| if (i / 7) % 3 == 0 { 0.0 } else { 1.0 }).collect();
        let faint: Vec<f32> = doc.iter().map(|v| 0.4 + 0.05 * v).collect();
        let negative: Vec<f32> = doc.iter().map(|v| 1.0 - v).collect();
        assert!((ncc(&faint, &doc) - 1.0).abs() < 1e-6);
        assert!((legibility(&negative, &doc, 20, 20) - 1.0).abs() < 1e-6);
        assert_eq!(ncc(&vec![0.5; 400], &doc), 0.0);
    }

    #[test]
    fn ssim_and_psnr_match_hand_values() {
        // Identical images: SSIM 1; a constant offset δ gives MSE δ², so PSNR = 20 log10(peak/δ).
        let a: Vec<f32> = (0..256).map(|i| (i % 16) as f32 / 16.0).collect();
        assert!((ssim(&a, &a, 16, 16, 1.0) - 1.0).abs() < 1e-9);
        let b: Vec<f32> = a.iter().map(|v| v + 0.1).collect();
        assert!((psnr(&a, &b, 1.0) - 20.0).abs() < 1e-3);
        // SSIM of an image against its negative is strongly negative (structure term −1).
        let n: Vec<f32> = a.iter().map(|v| 1.0 - v).collect();
        assert!(ssim(&a, &n, 16, 16, 1.0) < 0.0);
    }

    #[test]
    fn gaussian_blur_preserves_the_mean_and_smooths() {
        let img: Vec<f32> = (0..100).map(|i| if i == 55 { 1.0 } else { 0.0 }).collect();
        let b = gaussian_blur(&img, 10, 10, 1.0);
        let s: f32 = b.iter().sum();
        assert!((s - 1.0).abs() < 1e-4, "{s}");
        // The 1-D kernel at σ = 1 puts 0.4 in the centre tap: 0.16 in 2-D (Gaussian value 1/(2π) ≈ 0.159).
        assert!((b[55] - 0.159).abs() < 0.01, "{}", b[55]);
    }
}
