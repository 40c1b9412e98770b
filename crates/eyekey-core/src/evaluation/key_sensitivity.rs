//! Key sensitivity: legibility as a viewer's wavefront and cone parameters move away from the target's.

use crate::evaluation::{median, EvaluationError, EvaluationOptions, KeySensitivity, Reference};
use crate::physics::display::DisplayGeometry;
use crate::physics::observer::{Lens, Observer};
use crate::physics::profile::VisionProfile;
use crate::physics::spectral::{coupling, sample_observer_parameters, ConeFundamentals, SpectralSensitivity};
use crate::physics::transport::{EyePosition, TransportCache, TransportOptions};
use crate::physics::zernike::ZernikeCoefficients;
use rand::{Rng, SeedableRng};
use std::sync::atomic::{AtomicBool, Ordering};

/// Optical steps along each direction, µm RMS.
const OPTICAL_STEPS_UM: [f64; 6] = [0.02, 0.05, 0.1, 0.2, 0.4, 0.8];
/// Spectral steps along each direction, in population SDs.
const SPECTRAL_STEPS_SD: [f64; 5] = [0.25, 0.5, 1.0, 2.0, 4.0];
/// The Zernike terms moved: j = 3..=14.
const TERMS: std::ops::RangeInclusive<usize> = 3..=14;

/// What a key-sensitivity measurement looks at.
pub(crate) struct KeySensitivityProbe<'a> {
    pub display: &'a DisplayGeometry,
    pub l: &'a [f32],
    pub target: &'a VisionProfile,
    pub reference: &'a Reference,
    pub options: &'a EvaluationOptions,
    pub topts: &'a TransportOptions,
    pub cache: &'a TransportCache,
    pub cancel: &'a AtomicBool,
}

/// A random unit direction in `dim` dimensions (uniform in the cube, normalised).
fn random_direction(rng: &mut impl Rng, dim: usize) -> Vec<f64> {
    let dir: Vec<f64> = (0..dim).map(|_| rng.gen::<f64>() * 2.0 - 1.0).collect();
    let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-12);
    dir.into_iter().map(|v| v / norm).collect()
}

impl KeySensitivityProbe<'_> {
    /// The first step at which legibility falls below the threshold (the largest step if it never does).
    fn first_below(&self, legs: &[f64], steps: &[f64]) -> f64 {
        steps
            .iter()
            .zip(legs)
            .find(|(_, l)| **l < self.options.threshold)
            .map(|(s, _)| *s)
            .unwrap_or(*steps.last().unwrap_or(&0.0))
    }

    pub(crate) fn run(&self) -> Result<KeySensitivity, EvaluationError> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.options.seed ^ 0x5EED);
        let base_w = self
            .target
            .effective_wavefront()
            .map_err(crate::physics::observer::ObserverError::from)?;
        let cones_std = self.target.cone_fundamentals();
        let (optical_legibility, mut radii) = self.optical(&mut rng, &base_w, &cones_std)?;
        let (spectral_legibility, mut sradii) = self.spectral(&mut rng, &base_w, &cones_std)?;
        let optical_radius_um = median(&mut radii);
        let spectral_radius_sd = median(&mut sradii);
        let (d_eff, typical) = population_spread();
        let optical_bits = d_eff * (typical / optical_radius_um.max(1e-9)).log2().max(0.0);
        let spectral_bits = 8.0 * ((2.0f64 * 8.0).sqrt() / spectral_radius_sd.max(1e-9)).log2().max(0.0);
        Ok(KeySensitivity {
            optical_steps_um: OPTICAL_STEPS_UM.to_vec(),
            optical_legibility,
            optical_radius_um,
            spectral_steps_sd: SPECTRAL_STEPS_SD.to_vec(),
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
                self.options.key_directions, d_eff, typical
            ),
        })
    }

    /// The target's eye with wavefront `w` (measured at the profile's reference wavelength) and cones `cones`.
    fn observer(&self, w: &ZernikeCoefficients, cones: &ConeFundamentals) -> Result<Observer, EvaluationError> {
        let lens = Lens::Eye {
            wavefront: w,
            reference_nm: self.target.reference_wavelength(),
        };
        let eye = EyePosition::default();
        Ok(Observer::from_parts(
            self.display,
            lens,
            cones,
            eye,
            self.topts,
            self.options.optics,
            self.cache,
        )?)
    }

    /// Legibility along random directions in the wavefront terms; returns it and each direction's radius.
    fn optical(
        &self,
        rng: &mut impl Rng,
        base_w: &ZernikeCoefficients,
        cones: &ConeFundamentals,
    ) -> Result<(Vec<Vec<f64>>, Vec<f64>), EvaluationError> {
        let (mut all, mut radii) = (Vec::new(), Vec::new());
        for _ in 0..self.options.key_directions {
            let dir = random_direction(rng, TERMS.count());
            let mut legs = Vec::new();
            for &step in &OPTICAL_STEPS_UM {
                if self.cancel.load(Ordering::Relaxed) {
                    return Err(EvaluationError::Cancelled);
                }
                let mut w = base_w.clone();
                for (k, j) in TERMS.enumerate() {
                    w.coefficients_um[j] += step * dir[k];
                }
                let o = self.observer(&w, cones)?;
                legs.push(self.reference.score_observer("", &o, self.l).0.legibility);
            }
            radii.push(self.first_below(&legs, &OPTICAL_STEPS_UM));
            all.push(legs);
        }
        Ok((all, radii))
    }

    /// Legibility along random directions of the 8 cone parameters (the target's own transport); returns it
    /// and each direction's radius.
    fn spectral(
        &self,
        rng: &mut impl Rng,
        base_w: &ZernikeCoefficients,
        cones: &ConeFundamentals,
    ) -> Result<(Vec<Vec<f64>>, Vec<f64>), EvaluationError> {
        let d = self.display;
        let t_obs = self.observer(base_w, cones)?;
        let base_params = match &self.target.spectral {
            SpectralSensitivity::Parameters(p) => p.clone(),
            SpectralSensitivity::Table { .. } => Default::default(),
        };
        let sds = parameter_sds();
        let (mut all, mut radii) = (Vec::new(), Vec::new());
        for _ in 0..self.options.key_directions {
            let dir = random_direction(rng, 8);
            let mut legs = Vec::new();
            for &step in &SPECTRAL_STEPS_SD {
                let mut v = params_vec(&base_params);
                for i in 0..8 {
                    v[i] += step * dir[i] * sds[i];
                }
                let mut p = base_params.clone();
                set_params(&mut p, &v);
                let c = coupling(&d.projectors, &p.cone_fundamentals()).c;
                let o = Observer::with_coupling(t_obs.transports.clone(), c, d.l_max);
                legs.push(self.reference.score_observer("", &o, self.l).0.legibility);
            }
            radii.push(self.first_below(&legs, &SPECTRAL_STEPS_SD));
            all.push(legs);
        }
        Ok((all, radii))
    }
}

/// Population SDs of the 8 cone parameters, estimated from 400 samples of the shipped model.
fn parameter_sds() -> [f64; 8] {
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
}

/// The population's spread over j = 3..=14 at 6 mm from the shipped statistics: the effective number of
/// dimensions (participation ratio of the variances) and the RMS distance between two random people, µm.
fn population_spread() -> (f64, f64) {
    let sd2: Vec<f64> = crate::physics::population::indiana_stats(6.0)
        .iter()
        .filter(|t| TERMS.contains(&t.j))
        .map(|t| t.sd_um * t.sd_um)
        .collect();
    let total: f64 = sd2.iter().sum();
    let d_eff = total * total / sd2.iter().map(|v| v * v).sum::<f64>().max(1e-30);
    (d_eff, (2.0 * total).sqrt())
}

pub(crate) fn params_vec(p: &crate::physics::spectral::ObserverParameters) -> [f64; 8] {
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

pub(crate) fn set_params(p: &mut crate::physics::spectral::ObserverParameters, v: &[f64; 8]) {
    p.od_lens_pct = v[0].max(-99.0);
    p.od_macula_pct = v[1].max(-99.0);
    p.od_l_pct = v[2].max(-99.0);
    p.od_m_pct = v[3].max(-99.0);
    p.od_s_pct = v[4].max(-99.0);
    p.shift_l_nm = v[5].clamp(-15.0, 15.0);
    p.shift_m_nm = v[6].clamp(-15.0, 15.0);
    p.shift_s_nm = v[7].clamp(-15.0, 15.0);
}
