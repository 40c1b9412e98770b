//! Key sensitivity: legibility as a viewer's wavefront and cone parameters move away from the target's.

use crate::physics::display::DisplayGeometry;
use crate::physics::observer::Observer;
use crate::physics::profile::VisionProfile;
use crate::physics::spectral::{coupling, sample_observer_parameters, SpectralSensitivity};
use crate::physics::transport::{EyePosition, TransportOptions};
use rand::{Rng, SeedableRng};
use std::sync::atomic::{AtomicBool, Ordering};

#[allow(unused_imports)]
use super::*;

pub(crate) fn key_sensitivity(
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
        .map_err(crate::physics::observer::ObserverError::from)?;
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
    let sd2: Vec<f64> = crate::physics::population::indiana_stats(6.0)
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
