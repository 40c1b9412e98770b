//! The camera attacker: an ideal lens behind an RGB sensor or one-band filters.

use crate::physics::spectral::ConeFundamentals;

#[allow(unused_imports)]
use super::*;

/// Camera channels: Gaussian spectral sensitivities of a typical RGB sensor (peaks 600/535/460 nm, FWHM
/// 80/80/60 nm), peak-normalised.
pub(crate) fn camera_rgb() -> ConeFundamentals {
    let g = |centre: f64, fwhm: f64| -> Vec<f64> {
        let s = fwhm / 2.354_820_045;
        crate::physics::spectral::wavelengths_nm()
            .map(|l| (-(l - centre).powi(2) / (2.0 * s * s)).exp())
            .collect()
    };
    ConeFundamentals {
        l: g(600.0, 80.0),
        m: g(535.0, 80.0),
        s: g(460.0, 60.0),
    }
}
