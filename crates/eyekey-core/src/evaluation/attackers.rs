//! The attackers and moved viewers an evaluation (and the encoder's decoys) look through: a camera with an
//! ideal lens behind an RGB sensor or one-band filters, and the target's eye moved on a ring.

use std::sync::Arc;

use crate::physics::display::DisplayGeometry;
use crate::physics::observer::Observer;
use crate::physics::spectral::{wavelengths_nm, ConeFundamentals};
use crate::physics::transport::{EyePosition, TransportMatrix};
use crate::physics::zernike::{Prescription, ZernikeCoefficients};

/// Camera channels: Gaussian spectral sensitivities of a typical RGB sensor (peaks 600/535/460 nm, FWHM
/// 80/80/60 nm), peak-normalised.
pub(crate) fn camera_rgb() -> ConeFundamentals {
    let g = |centre: f64, fwhm: f64| -> Vec<f64> {
        let s = fwhm / 2.354_820_045;
        wavelengths_nm()
            .map(|l| (-(l - centre).powi(2) / (2.0 * s * s)).exp())
            .collect()
    };
    ConeFundamentals {
        l: g(600.0, 80.0),
        m: g(535.0, 80.0),
        s: g(460.0, 60.0),
    }
}

/// An ideal camera lens of `aperture_mm` focused `focus_d` dioptres off the display: pure defocus.
pub(crate) fn camera_lens(focus_d: f64, aperture_mm: f64) -> ZernikeCoefficients {
    let rx = Prescription {
        sphere_d: focus_d,
        cylinder_d: 0.0,
        axis_deg: 0.0,
    };
    ZernikeCoefficients::from_prescription(&rx, aperture_mm)
}

/// The spectral coupling of a filter that passes projector band `band` alone, equally to all three channels.
fn one_band_coupling(n_bands: usize, band: usize) -> Vec<[f64; 3]> {
    (0..n_bands)
        .map(|m| if m == band { [1.0; 3] } else { [0.0; 3] })
        .collect()
}

/// One observer per projector band: the camera behind a filter that passes that band alone.
pub(crate) fn one_band_observers(transports: Vec<Arc<TransportMatrix>>, display: &DisplayGeometry) -> Vec<Observer> {
    (0..display.n_bands())
        .map(|band| {
            Observer::with_coupling(
                transports.clone(),
                one_band_coupling(display.n_bands(), band),
                display.l_max,
            )
        })
        .collect()
}

/// The camera's channel configurations: the sensor's R, G and B, then each band isolated by a filter.
/// `rgb` is the sensor's coupling c_na per band.
pub(crate) fn camera_channels(rgb: &[[f64; 3]], n_bands: usize) -> Vec<(String, Vec<[f64; 3]>)> {
    let mut configs: Vec<(String, Vec<[f64; 3]>)> = ["R", "G", "B"]
        .iter()
        .enumerate()
        .map(|(ch, name)| (name.to_string(), rgb.iter().map(|c| [c[ch], c[ch], c[ch]]).collect()))
        .collect();
    for band in 0..n_bands {
        configs.push((format!("filter_band_{band}"), one_band_coupling(n_bands, band)));
    }
    configs
}

/// Four eye positions on a ring of radius `r_mm` around the design position: right, left, up, down.
pub fn head_ring(r_mm: f64) -> [EyePosition; 4] {
    [(r_mm, 0.0), (-r_mm, 0.0), (0.0, r_mm), (0.0, -r_mm)].map(|(x_mm, y_mm)| EyePosition { x_mm, y_mm, dz_mm: 0.0 })
}

/// `n` eye positions evenly spaced on a ring of radius `r_mm`, the first to the right; for `n` = 4 the
/// positions of [`head_ring`].
pub fn ring(r_mm: f64, n: u32) -> Vec<EyePosition> {
    if n == 4 {
        return head_ring(r_mm).to_vec();
    }
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            EyePosition {
                x_mm: r_mm * a.cos(),
                y_mm: r_mm * a.sin(),
                dz_mm: 0.0,
            }
        })
        .collect()
}
