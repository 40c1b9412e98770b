//! An eye's modulation transfer function from its wavefront, and the published mean of human eyes to check the
//! sampled population against (docs/design.md §4, "A population that looks like people").
//!
//! The optical transfer function of an incoherent system is the normalised autocorrelation of its pupil function
//! P(x) = A(x)·exp(i2πW(x)/λ) (Goodman, *Introduction to Fourier Optics*, 3rd ed., §6.3.1, Eq. 6-20): a shift of the
//! pupil by Δ (mm) is the spatial frequency Δ/λ cycles per radian, Δ·π/(180·λ) cycles per degree. It is computed
//! as |F{P}|² transformed back, on a pupil sampled `samples_across` points per diameter and zero-padded four times
//! (so no shift wraps round). The radial MTF is |OTF| averaged over directions.

use rustfft::num_complex::Complex64;
use rustfft::FftPlanner;

use crate::physics::zernike::ZernikeCoefficients;

/// The radially averaged MTF of a pupil of `wavefront`'s diameter with that wavefront at `wavelength_nm`: pairs
/// (cycles per degree, MTF), from 0 up to the diffraction cutoff d·π/(180·λ), one per pupil sample of shift.
pub fn radial_mtf(wavefront: &ZernikeCoefficients, wavelength_nm: f64, samples_across: usize) -> Vec<(f64, f64)> {
    let n = samples_across.max(8);
    let m = 4 * n;
    let d = wavefront.pupil_diameter_mm;
    let step = d / n as f64;
    let lambda_um = wavelength_nm * 1e-3;
    let mut field = vec![Complex64::new(0.0, 0.0); m * m];
    for j in 0..n {
        for i in 0..n {
            // Sample centres across the pupil, origin at its centre.
            let (x, y) = ((i as f64 + 0.5) * step - d / 2.0, (j as f64 + 0.5) * step - d / 2.0);
            if x * x + y * y <= d * d / 4.0 {
                let phase = 2.0 * std::f64::consts::PI * wavefront.wavefront_um(x, y) / lambda_um;
                field[j * m + i] = Complex64::from_polar(1.0, phase);
            }
        }
    }
    let mut planner = FftPlanner::new();
    let forward = planner.plan_fft_forward(m);
    let inverse = planner.plan_fft_inverse(m);
    crate::physics::fourier::fft2(&mut field, m, forward.as_ref());
    for v in field.iter_mut() {
        *v = Complex64::new(v.norm_sqr(), 0.0);
    }
    crate::physics::fourier::fft2(&mut field, m, inverse.as_ref());
    let zero = field[0].norm();
    // Average |OTF| over directions in rings one sample of shift wide (shift k samples: frequency k·step/λ).
    let rings = n + 1;
    let (mut sum, mut count) = (vec![0.0; rings], vec![0usize; rings]);
    for j in 0..m {
        for i in 0..m {
            let (dx, dy) = (wrap(i, m), wrap(j, m));
            let r = ((dx * dx + dy * dy) as f64).sqrt().round() as usize;
            if r < rings {
                sum[r] += field[j * m + i].norm() / zero;
                count[r] += 1;
            }
        }
    }
    let per_sample = step / (wavelength_nm * 1e-6) * std::f64::consts::PI / 180.0;
    (0..rings)
        .filter(|&r| count[r] > 0)
        .map(|r| (r as f64 * per_sample, sum[r] / count[r] as f64))
        .collect()
}

/// The signed offset of FFT index `i` of `m`.
fn wrap(i: usize, m: usize) -> i64 {
    if i <= m / 2 {
        i as i64
    } else {
        i as i64 - m as i64
    }
}

/// `mtf` (pairs from [`radial_mtf`]) at `u` cycles per degree, linearly interpolated; 0 past its last frequency.
pub fn mtf_at(mtf: &[(f64, f64)], u: f64) -> f64 {
    for w in mtf.windows(2) {
        let ((u0, m0), (u1, m1)) = (w[0], w[1]);
        if (u0..=u1).contains(&u) {
            return m0 + (m1 - m0) * (u - u0) / (u1 - u0);
        }
    }
    0.0
}

/// The diffraction-limited MTF of a circular pupil of `pupil_mm` at `wavelength_nm` and `u` cycles per degree
/// (Goodman §6.3.2, Eq. 6-32), with the cutoff u₀ = d·π·10⁶/(180·λ) of Watson 2013, Eq. 2.
pub fn diffraction_limited_mtf(u: f64, pupil_mm: f64, wavelength_nm: f64) -> f64 {
    let u0 = pupil_mm * std::f64::consts::PI * 1e6 / (180.0 * wavelength_nm);
    let s = u / u0;
    if s >= 1.0 {
        return 0.0;
    }
    2.0 / std::f64::consts::PI * (s.acos() - s * (1.0 - s * s).sqrt())
}

/// The mean human optical MTF at 555 nm for a pupil of `pupil_mm` (2–6 mm) at `u` cycles per degree: Watson
/// 2013 (J. Vision 13(6):18, Eq. 4), fitted to the radially averaged MTFs of the Indiana Aberration Study's 200
/// eyes (the statistics eyekey's population is drawn from): (1 + (u/u₁)²)^−0.62 · √D(u), with
/// u₁ = 21.95 − 5.512·d + 0.3922·d² and D the diffraction-limited MTF.
pub fn watson_mean_mtf(u: f64, pupil_mm: f64) -> f64 {
    let d = pupil_mm;
    let u1 = 21.95 - 5.512 * d + 0.3922 * d * d;
    (1.0 + (u / u1).powi(2)).powf(-0.62) * diffraction_limited_mtf(u, d, 555.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_perfect_eyes_mtf_is_the_closed_form_diffraction_limit() {
        // W = 0 over 3 mm at 555 nm: the autocorrelation of the disc, whose closed form is Goodman's Eq. 6-32.
        let mtf = radial_mtf(&ZernikeCoefficients::zero(3.0), 555.0, 48);
        let cutoff = 3.0 * std::f64::consts::PI * 1e6 / (180.0 * 555.0);
        assert!((mtf.last().unwrap().0 - cutoff).abs() < 1e-9);
        for u in [5.0, 15.0, 30.0, 60.0, 80.0] {
            let (got, want) = (mtf_at(&mtf, u), diffraction_limited_mtf(u, 3.0, 555.0));
            assert!((got - want).abs() < 0.02, "{u} c/deg: {got:.4} vs {want:.4}");
        }
        assert_eq!(mtf[0].1, 1.0);
    }

    #[test]
    fn defocus_lowers_the_mtf_and_watsons_formula_is_as_published() {
        // A quarter wave of defocus RMS (0.139 µm at 555 nm) takes contrast from the mid frequencies.
        let mut c = vec![0.0; 5];
        c[4] = 0.139;
        let blurred = radial_mtf(&ZernikeCoefficients::new(3.0, c).unwrap(), 555.0, 48);
        let sharp = radial_mtf(&ZernikeCoefficients::zero(3.0), 555.0, 48);
        assert!(mtf_at(&blurred, 30.0) < mtf_at(&sharp, 30.0) - 0.05);
        // Watson's formula by hand at 3 mm and 10 c/deg: u₁ = 21.95 − 16.536 + 3.5298 = 8.9438,
        // (1 + (10/8.9438)²)^−0.62 = 2.2501^−0.62 = 0.60483; D(10) with u₀ = 94.342: s = 0.10600, D = 0.86529,
        // √D = 0.93021.
        let by_hand = 0.60483 * 0.93021;
        assert!(
            (watson_mean_mtf(10.0, 3.0) - by_hand).abs() < 2e-4,
            "{}",
            watson_mean_mtf(10.0, 3.0)
        );
    }
}
