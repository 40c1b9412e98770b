//! Is it actually secret? Fidelity for the target and readability for everybody else (DESIGN §4).
//!
//! Readability is judged contrast-invariantly: an attacker stretches contrast and denoises, so the score is
//! the best |normalised cross-correlation| between the document's luminance and the view's luminance after
//! Gaussian denoising at a few strengths ([`legibility`]). Its threshold is calibrated against OCR
//! (see `docs/legibility-calibration.md`). Fidelity is PSNR and SSIM (Wang et al. 2004) against the objective.
//!
//! Every simulated view here uses a sub-ray jitter seed different from the encoder's, so an encoding cannot
//! look good merely by fitting the sampling pattern of its own transport operator.

use std::sync::atomic::{AtomicBool, Ordering};

use image::{Rgb, RgbImage};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::display::DisplayGeometry;
use crate::imaging;
use crate::observer::Observer;
use crate::optics::profile::VisionProfile;
use crate::optics::zernike::ZernikeCoefficients;
use crate::population::{sample_population, SamplingScope};
use crate::spectral::{coupling, sample_observer_parameters, ConeFundamentals, SpectralSensitivity};
use crate::transport::{EyePosition, TransportOptions};

/// Default legibility threshold: views scoring at or above it are counted as readable.
/// Calibrated against OCR in `docs/legibility-calibration.md`: the lowest legibility at which tesseract, after
/// an attacker's enhancements, read any of 400 simulated PIN views (its 50 % point is 0.60). People read some
/// noisy views below it, so secrecy claims should also be checked at a stricter threshold.
pub const DEFAULT_THRESHOLD: f64 = 0.38;

/// Photopic luminance from LMS: the CIE 2008 physiologically-relevant V(λ) = 0.68990272 L + 0.34832189 M
/// (CIE 170-2:2015; the LMS→XYZ matrix of `data/README.md` §1).
pub fn luminance(lms: &[f32]) -> Vec<f32> {
    lms.chunks_exact(3)
        .map(|p| 0.689_902_7 * p[0] + 0.348_321_9 * p[1])
        .collect()
}

/// Luminance (Rec. 709 / sRGB weights on linear RGB) of an sRGB image, row-major.
pub fn image_luminance(img: &RgbImage) -> Vec<f32> {
    imaging::linear_rgb(img)
        .iter()
        .map(|c| (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]) as f32)
        .collect()
}

/// Pearson correlation of two equally long images; 0 when either is constant.
pub fn ncc(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    let ma = a.iter().map(|v| *v as f64).sum::<f64>() / n;
    let mb = b.iter().map(|v| *v as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (*x as f64 - ma, *y as f64 - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa <= 1e-30 || sbb <= 1e-30 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// Separable Gaussian blur with edge clamping (σ in pixels; σ = 0 returns a copy).
pub fn gaussian_blur(img: &[f32], width: usize, height: usize, sigma: f64) -> Vec<f32> {
    if sigma <= 0.0 {
        return img.to_vec();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f64 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| (v / ks) as f32).collect();
    let mut tmp = vec![0f32; img.len()];
    tmp.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut s = 0f32;
            for (i, kv) in k.iter().enumerate() {
                let xx = (x as isize + i as isize - r).clamp(0, width as isize - 1) as usize;
                s += kv * img[y * width + xx];
            }
            *out = s;
        }
    });
    let mut out = vec![0f32; img.len()];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut s = 0f32;
            for (i, kv) in k.iter().enumerate() {
                let yy = (y as isize + i as isize - r).clamp(0, height as isize - 1) as usize;
                s += kv * tmp[yy * width + x];
            }
            *o = s;
        }
    });
    out
}

/// Denoising strengths (σ, pixels) an attacker tries before reading.
pub const DENOISE_SIGMAS: [f64; 3] = [0.0, 0.7, 1.5];

/// Contrast-invariant legibility of a view (luminance, row-major) against the document's luminance:
/// max over [`DENOISE_SIGMAS`] of |NCC(G_σ * view, document)|. A negative image is as readable as a positive.
pub fn legibility(view: &[f32], document: &[f32], width: usize, height: usize) -> f64 {
    DENOISE_SIGMAS
        .iter()
        .map(|&s| ncc(&gaussian_blur(view, width, height, s), document).abs())
        .fold(0.0, f64::max)
}

/// PSNR in dB of `a` against reference `b` for a peak value `peak`.
pub fn psnr(a: &[f32], b: &[f32], peak: f64) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64;
    if mse <= 1e-30 {
        return 99.0;
    }
    10.0 * (peak * peak / mse).log10()
}

/// Mean SSIM (Wang, Bovik, Sheikh & Simoncelli 2004): Gaussian window σ = 1.5, K1 = 0.01, K2 = 0.03, data
/// range `range`.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize, range: f64) -> f64 {
    let c1 = (0.01 * range).powi(2) as f32;
    let c2 = (0.03 * range).powi(2) as f32;
    let blur = |v: &[f32]| gaussian_blur(v, width, height, 1.5);
    let mu_a = blur(a);
    let mu_b = blur(b);
    let aa: Vec<f32> = a.iter().map(|v| v * v).collect();
    let bb: Vec<f32> = b.iter().map(|v| v * v).collect();
    let ab: Vec<f32> = a.iter().zip(b).map(|(x, y)| x * y).collect();
    let (saa, sbb, sab) = (blur(&aa), blur(&bb), blur(&ab));
    let mut total = 0.0;
    for i in 0..a.len() {
        let (ma, mb) = (mu_a[i], mu_b[i]);
        let va = saa[i] - ma * ma;
        let vb = sbb[i] - mb * mb;
        let cov = sab[i] - ma * mb;
        total += (((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))) as f64;
    }
    total / a.len().max(1) as f64
}

/// Scores of one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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

/// The document as the evaluation sees it: luminance on the retinal grid and the objective's level.
pub struct Reference {
    /// Document luminance (linear, 0..1), row-major on the retinal grid.
    pub document: Vec<f32>,
    /// Grid width.
    pub width: usize,
    /// Grid height.
    pub height: usize,
    /// The objective level (fraction of the display white the target was asked to see).
    pub level: f64,
    /// Legibility threshold.
    pub threshold: f64,
}

impl Reference {
    /// From an sRGB document resized to the retinal grid.
    pub fn new(document: &RgbImage, width: u32, height: u32, level: f64, threshold: f64) -> Self {
        let resized = imaging::resize(document, width, height);
        Self {
            document: image_luminance(&resized),
            width: width as usize,
            height: height as usize,
            level,
            threshold,
        }
    }

    /// Scores a luminance view; `white_luminance` is the viewer's luminance of the display's full white.
    pub fn score(&self, label: &str, view_luminance: &[f32], white_luminance: f64) -> ViewScore {
        let leg = legibility(view_luminance, &self.document, self.width, self.height);
        let norm: Vec<f32> = view_luminance
            .iter()
            .map(|v| (*v as f64 / white_luminance) as f32)
            .collect();
        let objective: Vec<f32> = self.document.iter().map(|v| (*v as f64 * self.level) as f32).collect();
        ViewScore {
            label: label.to_string(),
            legibility: leg,
            ncc: ncc(view_luminance, &self.document),
            psnr_db: psnr(&norm, &objective, self.level),
            ssim: ssim(&norm, &objective, self.width, self.height, self.level),
            readable: leg >= self.threshold,
        }
    }

    /// Scores what `observer` sees of light field `l`; returns the score and the picture.
    pub fn score_observer(&self, label: &str, observer: &Observer, l: &[f32]) -> (ViewScore, RgbImage) {
        let view = observer.view(l);
        let lum = luminance(&view);
        let white = 0.689_902_7 * observer.white[0] + 0.348_321_9 * observer.white[1];
        (self.score(label, &lum, white), observer.picture(&view))
    }
}

/// Options of an evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default)]
pub struct EvaluationOptions {
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
}

impl Default for EvaluationOptions {
    fn default() -> Self {
        Self {
            population: 20,
            seed: 20_000,
            threshold: DEFAULT_THRESHOLD,
            sub_rays: 16,
            camera_focus_d: vec![-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0],
            camera_apertures_mm: vec![2.0, 4.0, 6.0],
            key_directions: 3,
            head_offsets_mm: vec![0.5, 1.0, 2.0, 4.0],
            saved_population_views: 3,
        }
    }
}

/// Summary of the population's readability.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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

/// The camera attacker's best case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CameraSummary {
    /// The best configuration's score.
    pub best: ViewScore,
    /// Every configuration tried.
    pub tried: Vec<ViewScore>,
}

/// Legibility as a viewer's parameters move away from the target's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct HeadMovement {
    /// Offsets tried (mm), each in four directions.
    pub offsets_mm: Vec<f64>,
    /// Worst legibility over the four directions, per offset.
    pub worst_legibility: Vec<f64>,
    /// Largest offset up to which every tried position still reads.
    pub readable_radius_mm: f64,
}

/// The whole evaluation report (`report.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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
    Observer(#[from] crate::observer::ObserverError),
    /// The cancel flag was raised.
    #[error("cancelled")]
    Cancelled,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let idx = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[idx.min(sorted.len() - 1)]
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    percentile(v, 0.5)
}

/// Camera channels: Gaussian spectral sensitivities of a typical RGB sensor (peaks 600/535/460 nm, FWHM
/// 80/80/60 nm), peak-normalised.
fn camera_rgb() -> ConeFundamentals {
    let g = |centre: f64, fwhm: f64| -> Vec<f64> {
        let s = fwhm / 2.354_820_045;
        crate::spectral::wavelengths_nm()
            .map(|l| (-(l - centre).powi(2) / (2.0 * s * s)).exp())
            .collect()
    };
    ConeFundamentals {
        l: g(600.0, 80.0),
        m: g(535.0, 80.0),
        s: g(460.0, 60.0),
    }
}

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
                    &crate::optics::zernike::Prescription {
                        sphere_d: focus,
                        cylinder_d: 0.0,
                        axis_deg: 0.0,
                    },
                    aperture,
                );
                let tr = crate::transport::TransportCache::global()
                    .get_or_build(display, &w, EyePosition::default(), &topts)
                    .map_err(crate::observer::ObserverError::from)?;
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

fn key_sensitivity(
    display: &DisplayGeometry,
    l: &[f32],
    target: &VisionProfile,
    reference: &Reference,
    options: &EvaluationOptions,
    topts: &TransportOptions,
    cancel: &AtomicBool,
) -> Result<KeySensitivity, EvaluationError> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed ^ 0x5EED);
    let base_w = target
        .effective_wavefront()
        .map_err(crate::observer::ObserverError::from)?;
    let terms: Vec<usize> = (3..=14).collect();
    let optical_steps_um = vec![0.02, 0.05, 0.1, 0.2, 0.4, 0.8];
    let spectral_steps_sd = vec![0.25, 0.5, 1.0, 2.0, 4.0];
    let cones_std = target.cone_fundamentals();
    let threshold = options.threshold;
    let first_below = |legs: &[f64], steps: &[f64]| -> f64 {
        steps
            .iter()
            .zip(legs)
            .find(|(_, l)| **l < threshold)
            .map(|(s, _)| *s)
            .unwrap_or(*steps.last().unwrap_or(&0.0))
    };
    let mut optical_legibility = Vec::new();
    let mut radii = Vec::new();
    for _ in 0..options.key_directions {
        let dir: Vec<f64> = terms.iter().map(|_| rng.gen::<f64>() * 2.0 - 1.0).collect();
        let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-12);
        let mut legs = Vec::new();
        for &step in &optical_steps_um {
            if cancel.load(Ordering::Relaxed) {
                return Err(EvaluationError::Cancelled);
            }
            let mut w = base_w.clone();
            for (k, &j) in terms.iter().enumerate() {
                w.coefficients_um[j] += step * dir[k] / norm;
            }
            let o = Observer::from_parts(display, &w, &cones_std, EyePosition::default(), topts)?;
            legs.push(reference.score_observer("", &o, l).0.legibility);
        }
        radii.push(first_below(&legs, &optical_steps_um));
        optical_legibility.push(legs);
    }
    // Spectral: the same transport as the target, cones moved along random directions of the 8 parameters.
    let t_obs = Observer::from_parts(display, &base_w, &cones_std, EyePosition::default(), topts)?;
    let base_params = match &target.spectral {
        SpectralSensitivity::Parameters(p) => p.clone(),
        SpectralSensitivity::Table { .. } => Default::default(),
    };
    let sds = {
        // Population SDs per parameter, estimated from samples of the shipped model.
        let mut r2 = rand_chacha::ChaCha8Rng::seed_from_u64(99);
        let samples: Vec<[f64; 8]> = (0..400)
            .map(|_| params_vec(&sample_observer_parameters(&mut r2)))
            .collect();
        let mut sd = [0.0; 8];
        for (i, s) in sd.iter_mut().enumerate() {
            let m = samples.iter().map(|v| v[i]).sum::<f64>() / samples.len() as f64;
            *s = (samples.iter().map(|v| (v[i] - m).powi(2)).sum::<f64>() / samples.len() as f64).sqrt();
        }
        sd
    };
    let mut spectral_legibility = Vec::new();
    let mut sradii = Vec::new();
    for _ in 0..options.key_directions {
        let dir: Vec<f64> = (0..8).map(|_| rng.gen::<f64>() * 2.0 - 1.0).collect();
        let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-12);
        let mut legs = Vec::new();
        for &step in &spectral_steps_sd {
            let mut v = params_vec(&base_params);
            for i in 0..8 {
                v[i] += step * dir[i] / norm * sds[i];
            }
            let mut p = base_params.clone();
            set_params(&mut p, &v);
            let c = coupling(&display.projectors, &p.cone_fundamentals()).c;
            let o = Observer::with_coupling(t_obs.transport.clone(), c, display.l_max);
            legs.push(reference.score_observer("", &o, l).0.legibility);
        }
        sradii.push(first_below(&legs, &spectral_steps_sd));
        spectral_legibility.push(legs);
    }
    let optical_radius_um = median(&mut radii);
    let spectral_radius_sd = median(&mut sradii);
    // Population spread over j = 3..=14 at 6 mm from the shipped statistics.
    let sd2: Vec<f64> = crate::population::indiana_stats(6.0)
        .iter()
        .filter(|t| (3..=14).contains(&t.j))
        .map(|t| t.sd_um * t.sd_um)
        .collect();
    let total: f64 = sd2.iter().sum();
    let d_eff = total * total / sd2.iter().map(|v| v * v).sum::<f64>().max(1e-30);
    let typical = (2.0 * total).sqrt();
    let optical_bits = d_eff * (typical / optical_radius_um.max(1e-9)).log2().max(0.0);
    let spectral_bits = 8.0 * ((2.0f64 * 8.0).sqrt() / spectral_radius_sd.max(1e-9)).log2().max(0.0);
    Ok(KeySensitivity {
        optical_steps_um,
        optical_legibility,
        optical_radius_um,
        spectral_steps_sd,
        spectral_legibility,
        spectral_radius_sd,
        optical_bits,
        spectral_bits,
        empirical_bits: 0.0,
        method: format!(
            "Legibility along {} random directions from the target. Optical: directions in the 12 Zernike terms j=3..14, \
             distance = RMS µm; bits = D_eff·log2(d_pop/r) with D_eff = {:.1} (participation ratio of the Indiana SDs), \
             d_pop = {:.3} µm (RMS distance between two random people), r = median distance at which legibility falls \
             below threshold. Spectral: directions in the 8 Asano parameters in population SDs; bits = 8·log2(√16/r). \
             Both ignore correlations between parameters and treat the key cell as a ball: order-of-magnitude figures, \
             not a security proof. empirical_bits = −log2((readable+1)/(count+1)) from the population sample.",
            options.key_directions, d_eff, typical
        ),
    })
}

fn params_vec(p: &crate::spectral::ObserverParameters) -> [f64; 8] {
    [
        p.od_lens_pct,
        p.od_macula_pct,
        p.od_l_pct,
        p.od_m_pct,
        p.od_s_pct,
        p.shift_l_nm,
        p.shift_m_nm,
        p.shift_s_nm,
    ]
}

fn set_params(p: &mut crate::spectral::ObserverParameters, v: &[f64; 8]) {
    p.od_lens_pct = v[0].max(-99.0);
    p.od_macula_pct = v[1].max(-99.0);
    p.od_l_pct = v[2].max(-99.0);
    p.od_m_pct = v[3].max(-99.0);
    p.od_s_pct = v[4].max(-99.0);
    p.shift_l_nm = v[5].clamp(-15.0, 15.0);
    p.shift_m_nm = v[6].clamp(-15.0, 15.0);
    p.shift_s_nm = v[7].clamp(-15.0, 15.0);
}

/// One PNG with labelled tiles (objective, target, observers, worst person, camera's best) and a bar plot of
/// the population's legibility against the threshold.
pub fn contact_sheet(report: &Report, pictures: &[(String, RgbImage)]) -> RgbImage {
    let wanted = [
        "objective.png",
        "target.png",
        "observer_0.png",
        "population_worst.png",
        "camera_best.png",
    ];
    let tiles: Vec<(&str, &RgbImage)> = wanted
        .iter()
        .filter_map(|w| pictures.iter().find(|(n, _)| n == w).map(|(n, p)| (n.as_str(), p)))
        .collect();
    let tile = 160u32;
    let label_h = 24u32;
    let cols = tiles.len() as u32 + 1;
    let mut sheet = RgbImage::from_pixel(cols * (tile + 8) + 8, tile + label_h + 16, Rgb([255, 255, 255]));
    let score_of = |name: &str| -> Option<f64> {
        match name {
            "target.png" => Some(report.target.legibility),
            "observer_0.png" => report.observers.first().map(|s| s.legibility),
            "population_worst.png" => report.population.as_ref().map(|p| p.max_legibility),
            "camera_best.png" => report.camera.as_ref().map(|c| c.best.legibility),
            _ => None,
        }
    };
    for (k, (name, pic)) in tiles.iter().enumerate() {
        let x0 = 8 + k as u32 * (tile + 8);
        let scaled = image::imageops::resize(*pic, tile, tile, image::imageops::FilterType::Nearest);
        image::imageops::replace(&mut sheet, &scaled, x0 as i64, 8);
        let short = match *name {
            "population_worst.png" => "WORST".to_string(),
            other => other.trim_end_matches(".png").replace('_', " ").to_uppercase(),
        };
        let text = match score_of(name) {
            Some(s) => format!("{} {:.2}", short.split(' ').next().unwrap_or(""), s),
            None => short.split(' ').next().unwrap_or("").to_string(),
        };
        let label = crate::glyphs::render_text(&[&text], tile, label_h, 2);
        image::imageops::replace(&mut sheet, &label, x0 as i64, (tile + 12) as i64);
    }
    // Plot: one bar per sampled person (legibility), a red line at the threshold, the target in green.
    let x0 = 8 + tiles.len() as u32 * (tile + 8);
    let mut legs: Vec<f64> = report
        .population
        .as_ref()
        .map(|p| p.people.iter().map(|s| s.legibility).collect())
        .unwrap_or_default();
    legs.sort_by(|a, b| a.total_cmp(b));
    // One column per pixel: the sorted legibilities resampled to the plot's width (a quantile plot), so a
    // population of any size fills it.
    let y_of = |v: f64| 8 + tile - ((v.clamp(0.0, 1.0) * tile as f64) as u32).min(tile);
    if !legs.is_empty() {
        for x in 0..tile {
            let v = legs[(x as usize * legs.len() / tile as usize).min(legs.len() - 1)];
            for y in y_of(v)..8 + tile {
                sheet.put_pixel(x0 + x, y, Rgb([90, 90, 200]));
            }
        }
    }
    for x in x0..x0 + tile {
        sheet.put_pixel(x, y_of(report.threshold).min(7 + tile), Rgb([220, 0, 0]));
        sheet.put_pixel(x, y_of(report.target.legibility).min(7 + tile), Rgb([0, 170, 0]));
    }
    let label = crate::glyphs::render_text(&["PEOPLE"], tile, label_h, 2);
    image::imageops::replace(&mut sheet, &label, x0 as i64, (tile + 12) as i64);
    sheet
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
