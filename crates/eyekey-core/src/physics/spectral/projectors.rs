//! Projector spectra and the coupling matrix c_na = ∫ E_n x̄_a dλ (paper Eq. 12).

use crate::physics::spectral::{
    check_range, grid_integral, resample_onto_grid, trapezoid, validate_table, wavelengths_nm, ConeFundamentals,
    SpectralError, MIN_POWER_FRACTION_ON_GRID, WAVELENGTH_STEP_NM,
};
use serde::{Deserialize, Serialize};

// Projectors and the coupling matrix (Eq. 12)

/// Spectral power distribution E_n(λ) of one projector band of the multiband display (paper §5.1,
/// Fig. 9). Only the shape matters: [`power_on_grid`](Self::power_on_grid) normalises it to unit
/// radiant power.
///
/// JSON: `{"kind": "gaussian", "centre_nm": 450, "fwhm_nm": 20}` or `{"kind": "sampled",
/// "wavelengths_nm": [...], "power": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProjectorSpectrum {
    /// A Gaussian band, a good model of a projector behind a narrow band-pass filter.
    Gaussian {
        /// Centre wavelength in nm, 380..=780.
        #[cfg_attr(feature = "openapi", schema(minimum = 380.0, maximum = 780.0))]
        centre_nm: f64,
        /// Full width at half maximum in nm, 1..=200.
        #[cfg_attr(feature = "openapi", schema(minimum = 1.0, maximum = 200.0))]
        fwhm_nm: f64,
    },
    /// A measured spectrum (any scale), interpolated linearly, 0 outside its range.
    Sampled {
        /// Sample wavelengths in nm, strictly increasing, within 360..=850.
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::WavelengthSample>))]
        wavelengths_nm: Vec<f64>,
        /// Spectral power at each wavelength (non-negative).
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::SampleValue>))]
        power: Vec<f64>,
    },
}

/// Gaussian evaluated on the grid (unnormalised, peak 1) and its standard deviation in nm.
pub(crate) fn gaussian_on_grid(centre_nm: f64, fwhm_nm: f64) -> (Vec<f64>, f64) {
    // FWHM = 2√(2 ln 2)·σ.
    let sigma = fwhm_nm / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt());
    let values = wavelengths_nm()
        .map(|lambda| (-0.5 * ((lambda - centre_nm) / sigma).powi(2)).exp())
        .collect();
    (values, sigma)
}

impl ProjectorSpectrum {
    /// Checks the spectrum: a Gaussian needs a centre within 380..=780 nm and an FWHM within
    /// 1..=200 nm; a sampled table follows the table rules of [`SpectralSensitivity::validate`] and
    /// needs a positive power. Both must put at least 1 % of their power within the 390..=830 nm
    /// grid.
    pub fn validate(&self) -> Result<(), SpectralError> {
        let (field, fraction) = match self {
            Self::Gaussian { centre_nm, fwhm_nm } => {
                check_range("centre_nm", *centre_nm, 380.0, 780.0)?;
                check_range("fwhm_nm", *fwhm_nm, 1.0, 200.0)?;
                let (values, sigma) = gaussian_on_grid(*centre_nm, *fwhm_nm);
                // The 1-nm rectangle rule of the full Gaussian matches its integral σ√(2π) to < 3 %
                // for σ ≥ 0.42 nm (FWHM ≥ 1 nm), enough for this coarse check.
                let total = sigma * (2.0 * std::f64::consts::PI).sqrt();
                ("centre_nm", grid_integral(&values) / total)
            }
            Self::Sampled { wavelengths_nm, power } => {
                validate_table(wavelengths_nm, &[("power", power)])?;
                let total = trapezoid(wavelengths_nm, power);
                let on_grid = grid_integral(&resample_onto_grid(wavelengths_nm, power));
                let fraction = if total > 0.0 { on_grid / total } else { 0.0 };
                ("power", fraction)
            }
        };
        if fraction >= MIN_POWER_FRACTION_ON_GRID {
            Ok(())
        } else {
            Err(SpectralError::TooLittlePowerOnGrid {
                field: field.to_owned(),
                fraction,
            })
        }
    }

    /// E(λ) on the spectral grid, normalised to unit radiant power over the grid, Σ_k E(λ_k)·Δλ = 1
    /// (the same rectangle rule as [`coupling`]): a projector driven at L = L_max emits unit power.
    /// Returns all zeros if the spectrum has no power on the grid (rejected by
    /// [`validate`](Self::validate)).
    pub fn power_on_grid(&self) -> Vec<f64> {
        let mut values = match self {
            Self::Gaussian { centre_nm, fwhm_nm } => gaussian_on_grid(*centre_nm, *fwhm_nm).0,
            Self::Sampled { wavelengths_nm, power } => resample_onto_grid(wavelengths_nm, power),
        };
        let total = grid_integral(&values);
        if total > 0.0 && total.is_finite() {
            values.iter_mut().for_each(|v| *v /= total);
        } else {
            values.iter_mut().for_each(|v| *v = 0.0);
        }
        values
    }

    /// `q` wavelengths that stand for the band: its power cut into q bins of equal power (on the 1-nm grid,
    /// a grid step's power split where a bin edge falls inside it), each bin's power-weighted mean. With
    /// q = 1, the centroid.
    pub fn band_wavelengths_nm(&self, q: usize) -> Vec<f64> {
        let q = q.max(1);
        let e = self.power_on_grid();
        let total: f64 = e.iter().sum();
        if total <= 0.0 {
            return vec![self.centroid_nm(); q];
        }
        let share = total / q as f64;
        let (mut sums, mut moments) = (vec![0f64; q], vec![0f64; q]);
        let mut below = 0.0;
        for (l, &v) in wavelengths_nm().zip(&e) {
            // This step holds the cumulative power [below, below + v]; each bin takes its overlap.
            for (j, (s, m)) in sums.iter_mut().zip(moments.iter_mut()).enumerate() {
                let (lo, hi) = (j as f64 * share, (j + 1) as f64 * share);
                let take = ((below + v).min(hi) - below.max(lo)).max(0.0);
                *s += take;
                *m += take * l;
            }
            below += v;
        }
        sums.iter().zip(&moments).map(|(s, m)| m / s.max(1e-300)).collect()
    }

    /// The power-weighted mean wavelength of the band, nm: Σ λ·E(λ) / Σ E(λ) on the grid.
    pub fn centroid_nm(&self) -> f64 {
        let e = self.power_on_grid();
        let total: f64 = e.iter().sum();
        wavelengths_nm().zip(&e).map(|(l, v)| l * v).sum::<f64>() / total.max(1e-300)
    }
}

/// Coupling matrix of Eq. 12, c_na = ∫ E_n(λ) x̄_a(λ) dλ for a = L, M, S: the cone stimulus
/// produced by projector n at full intensity. Computed with the rectangle rule on the 1-nm grid,
/// c_na = Σ_k E_n(λ_k)·x̄_a(λ_k)·Δλ, the rule under which every E_n has unit power; the
/// fundamentals and the spectra are smooth on the 1-nm scale and vanish at the grid ends, so for
/// Gaussian bands of 10–40 nm FWHM this agrees with Simpson's rule on a 0.1-nm grid to about 1e-4 of
/// the band's largest coefficient (see the unit tests).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coupling {
    /// One row [c_nL, c_nM, c_nS] per projector band n.
    pub c: Vec<[f64; 3]>,
}

impl Coupling {
    /// Number of projector bands N.
    pub fn n_bands(&self) -> usize {
        self.c.len()
    }

    /// LMS of the display's white, all projectors at L_max: Σ_n c_n (Eq. 12 with I_n = 1).
    pub fn white_lms(&self) -> [f64; 3] {
        self.c
            .iter()
            .fold([0.0; 3], |acc, row| [acc[0] + row[0], acc[1] + row[1], acc[2] + row[2]])
    }
}

/// Computes the coupling matrix c_na (Eq. 12) of `projectors` for an observer with fundamentals
/// `cones`. Each projector spectrum is normalised to unit power first
/// ([`ProjectorSpectrum::power_on_grid`]).
///
/// ```
/// use eyekey_core::physics::spectral::{coupling, paper_projectors, stockman_sharpe_2deg};
/// let c = coupling(&paper_projectors(), stockman_sharpe_2deg());
/// assert_eq!(c.n_bands(), 4);
/// assert!(c.white_lms().iter().all(|&v| v > 0.0));
/// ```
pub fn coupling(projectors: &[ProjectorSpectrum], cones: &ConeFundamentals) -> Coupling {
    let channels = cones.channels();
    let c = projectors
        .iter()
        .map(|projector| {
            let power = projector.power_on_grid();
            channels.map(|x| power.iter().zip(x).map(|(e, x)| e * x).sum::<f64>() * WAVELENGTH_STEP_NM)
        })
        .collect();
    Coupling { c }
}

/// The four narrow-band projectors of the paper's prototype (§7, Fig. 9), modelled as Gaussians of
/// 20 nm FWHM centred at 450, 520, 590 and 640 nm (blue, green, amber, red band-pass filters). The
/// paper gives the spectra only as a plot; these centres span the gamut of an sRGB document (white
/// is a non-negative mix of the 450, 520 and 640 nm bands) and the 590 nm band adds the fourth,
/// metameric degree of freedom.
pub fn paper_projectors() -> Vec<ProjectorSpectrum> {
    [450.0, 520.0, 590.0, 640.0]
        .into_iter()
        .map(|centre_nm| ProjectorSpectrum::Gaussian {
            centre_nm,
            fwhm_nm: 20.0,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_band_is_cut_into_equal_power_bins_whose_mean_is_its_centroid() {
        let band = ProjectorSpectrum::Gaussian {
            centre_nm: 450.0,
            fwhm_nm: 20.0,
        };
        let centroid = band.centroid_nm();
        assert!((band.band_wavelengths_nm(1)[0] - centroid).abs() < 1e-9);
        for q in [2, 3, 5] {
            let l = band.band_wavelengths_nm(q);
            // Equal powers: the bins' centroids average to the band's.
            let mean = l.iter().sum::<f64>() / q as f64;
            assert!((mean - centroid).abs() < 1e-9, "q {q}: {mean} vs {centroid}");
            // A symmetric band gives symmetric bins, ascending.
            for j in 0..q {
                assert!(((l[j] - centroid) + (l[q - 1 - j] - centroid)).abs() < 1e-6, "{l:?}");
            }
            assert!(l.windows(2).all(|w| w[0] < w[1]), "{l:?}");
        }
        // Three bins of a Gaussian (σ = FWHM/2.3548): the outer bins' centroids lie at ±σ·φ(z)/(1/3)
        // with z = Φ⁻¹(2/3) = 0.430727 (the mean of a normal beyond z), ±1.0911σ = ±9.27 nm.
        let sigma = 20.0 / (8.0 * 2f64.ln()).sqrt();
        let z = 0.430_727_3f64;
        let phi = (-z * z / 2.0).exp() / (2.0 * std::f64::consts::PI).sqrt();
        let outer = sigma * phi * 3.0;
        let l = band.band_wavelengths_nm(3);
        assert!((l[2] - centroid - outer).abs() < 0.05, "{} vs {outer}", l[2] - centroid);
        assert!((l[1] - centroid).abs() < 1e-6);
    }
}
