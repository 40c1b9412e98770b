//! The eye's longitudinal chromatic aberration: Thibos, Ye, Zhang & Bradley (1992), "The chromatic eye: a new
//! reduced-eye model of ocular chromatic aberration in humans", Applied Optics 31(19), 3594–3600.
//!
//! The chromatic difference of refraction is R(λ) = p − q/(λ − c) dioptres with λ in µm, p = 1.68524,
//! q = 0.63346, c = 0.21410 (their Eq. 5, fitted to the reduced "chromatic eye"); R is 0 near 589 nm and negative
//! (myopic) at short wavelengths. A profile's coefficients are measured at a reference wavelength (555 nm unless
//! it says otherwise); at wavelength λ the eye has the extra refractive error R(λ) − R(λ_ref) (docs/design.md §2).

/// Thibos et al. (1992) p, dioptres.
const P_D: f64 = 1.68524;
/// Thibos et al. (1992) q, dioptre·µm.
const Q_D_UM: f64 = 0.63346;
/// Thibos et al. (1992) c, µm.
const C_UM: f64 = 0.21410;

/// The reference wavelength of a profile's coefficients when it states none, nm.
pub const DEFAULT_REFERENCE_WAVELENGTH_NM: f64 = 555.0;

/// R(λ) = p − q/(λ − c), the chromatic difference of refraction in dioptres at `wavelength_nm`.
pub fn chromatic_refraction_d(wavelength_nm: f64) -> f64 {
    P_D - Q_D_UM / (wavelength_nm * 1e-3 - C_UM)
}

/// The extra refractive error (dioptres, the sign of a spectacle prescription: negative = myopic) of an eye at
/// `wavelength_nm` relative to the wavelength its aberrations were measured at.
pub fn chromatic_defocus_d(wavelength_nm: f64, reference_nm: f64) -> f64 {
    chromatic_refraction_d(wavelength_nm) - chromatic_refraction_d(reference_nm)
}

/// The OSA Zernike defocus coefficient c₂⁰ (µm) of a refractive error of `m_d` dioptres over a pupil of radius
/// `pupil_radius_mm`: c₂⁰ = −M·r²/(4√3), the convention of [`crate::physics::zernike::Prescription`].
pub fn defocus_coefficient_um(m_d: f64, pupil_radius_mm: f64) -> f64 {
    -m_d * pupil_radius_mm * pupil_radius_mm / (4.0 * 3f64.sqrt())
}

/// `wavefront` (measured at `reference_nm`) as it is at `wavelength_nm`: its defocus term gains the eye's
/// chromatic difference of refraction between the two.
pub fn at_wavelength(
    wavefront: &crate::physics::zernike::ZernikeCoefficients,
    wavelength_nm: f64,
    reference_nm: f64,
) -> crate::physics::zernike::ZernikeCoefficients {
    let mut z = wavefront.clone();
    let m = chromatic_defocus_d(wavelength_nm, reference_nm);
    z.coefficients_um[4] += defocus_coefficient_um(m, z.pupil_radius_mm());
    z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::zernike::{Prescription, ZernikeCoefficients};

    #[test]
    fn the_formula_is_zero_near_589_nm_and_myopic_in_the_blue() {
        // Zero of p − q/(λ − c): λ = c + q/p = 0.21410 + 0.63346/1.68524 = 0.589986 µm.
        let zero_nm = (C_UM + Q_D_UM / P_D) * 1e3;
        assert!((zero_nm - 589.986).abs() < 1e-2, "{zero_nm}");
        assert!(chromatic_refraction_d(zero_nm).abs() < 1e-12);
        assert!(chromatic_refraction_d(450.0) < -0.99 && chromatic_refraction_d(450.0) > -1.01);
    }

    #[test]
    fn defocus_at_450_and_640_nm_matches_the_hand_computed_values() {
        // By hand: R(0.450) = 1.68524 − 0.63346/0.23590 = −1.000050; R(0.555) = 1.68524 − 0.63346/0.34090
        // = −0.172959; R(0.640) = 1.68524 − 0.63346/0.42590 = +0.197896. So −0.827 D in the blue band and
        // +0.371 D in the red, against 555 nm.
        let blue = chromatic_defocus_d(450.0, 555.0);
        let red = chromatic_defocus_d(640.0, 555.0);
        assert!((blue - (-1.000050 + 0.172959)).abs() < 2e-6, "{blue}");
        assert!((red - (0.197896 + 0.172959)).abs() < 2e-6, "{red}");
        assert_eq!(chromatic_defocus_d(555.0, 555.0), 0.0);
    }

    #[test]
    fn the_defocus_coefficient_follows_the_prescription_convention() {
        // −2.00 D over a 6 mm pupil is c₂⁰ = 2.598 µm (the prescription conversion, an independent code path).
        let c = defocus_coefficient_um(-2.0, 3.0);
        assert!((c - 2.598).abs() < 1e-3, "{c}");
        let rx = Prescription {
            sphere_d: -0.8,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        };
        let z = ZernikeCoefficients::from_prescription(&rx, 5.0);
        assert!((z.coefficients_um[4] - defocus_coefficient_um(-0.8, 2.5)).abs() < 1e-12);
    }
}
