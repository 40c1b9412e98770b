//! A viewer's spectral sensitivity: standard, individual parameters, or a measured table.

use crate::physics::spectral::{
    normalise_peak, resample_onto_grid, validate_table, ConeFundamentals, ObserverParameters, SpectralError,
};
use serde::{Deserialize, Serialize};

// Spectral sensitivity of a viewer

/// How a viewer's cone fundamentals are given: by physiological parameters (CIE 2006 + Asano 2016)
/// or by a measured table.
///
/// JSON: `{"kind": "parameters", "age_years": 45, "shift_l_nm": 1.5}` (missing parameters take the
/// standard observer's values) or `{"kind": "table", "wavelengths_nm": [...], "l": [...], "m":
/// [...], "s": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SpectralSensitivity {
    /// Individual-observer parameters.
    Parameters(ObserverParameters),
    /// Measured cone fundamentals (energy-based, linear; any scale, they are peak-normalised on
    /// use).
    Table {
        /// Sample wavelengths in nm, strictly increasing, within 360..=850.
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::WavelengthSample>))]
        wavelengths_nm: Vec<f64>,
        /// L-cone sensitivity at each wavelength.
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::SampleValue>))]
        l: Vec<f64>,
        /// M-cone sensitivity at each wavelength.
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::SampleValue>))]
        m: Vec<f64>,
        /// S-cone sensitivity at each wavelength.
        #[cfg_attr(feature = "openapi", schema(min_items = 10, value_type = Vec<crate::physics::spectral::SampleValue>))]
        s: Vec<f64>,
    },
}

impl Default for SpectralSensitivity {
    /// The CIE 2006 2° standard observer (age 32).
    fn default() -> Self {
        Self::Parameters(ObserverParameters::default())
    }
}

impl SpectralSensitivity {
    /// Checks the parameters ([`ObserverParameters::validate`]) or the table: at least 10 samples,
    /// equal lengths, finite, wavelengths strictly increasing within 360..=850 nm, sensitivities
    /// non-negative, and each channel positive somewhere on the 390..=830 nm grid.
    pub fn validate(&self) -> Result<(), SpectralError> {
        match self {
            Self::Parameters(p) => p.validate(),
            Self::Table {
                wavelengths_nm,
                l,
                m,
                s,
            } => {
                let columns: [(&str, &[f64]); 3] = [("l", l), ("m", m), ("s", s)];
                validate_table(wavelengths_nm, &columns)?;
                for (name, values) in columns {
                    let on_grid = resample_onto_grid(wavelengths_nm, values);
                    if !on_grid.iter().any(|&v| v > 0.0) {
                        return Err(SpectralError::NoSensitivityOnGrid { field: name.to_owned() });
                    }
                }
                Ok(())
            }
        }
    }

    /// The cone fundamentals on the spectral grid, each with a peak of 1. A table is interpolated
    /// linearly, with 0 outside its wavelength range, then peak-normalised on the grid.
    pub fn cone_fundamentals(&self) -> ConeFundamentals {
        match self {
            Self::Parameters(p) => p.cone_fundamentals(),
            Self::Table {
                wavelengths_nm,
                l,
                m,
                s,
            } => {
                let mut channels = [l, m, s].map(|v| resample_onto_grid(wavelengths_nm, v));
                channels.iter_mut().for_each(|c| normalise_peak(c));
                let [l, m, s] = channels;
                ConeFundamentals { l, m, s }
            }
        }
    }
}
