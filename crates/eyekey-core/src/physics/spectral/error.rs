//! Errors of the spectral model, each naming its field.
use crate::physics::spectral::MIN_POWER_FRACTION_ON_GRID;

// Errors

/// Invalid spectral input. Every message names the offending field (with an index for table
/// entries).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SpectralError {
    /// A number is NaN or infinite.
    #[error("{field} must be finite, got {value}")]
    NotFinite {
        /// Field name, e.g. `age_years` or `power[3]`.
        field: String,
        /// The offending value.
        value: f64,
    },
    /// A number lies outside its allowed closed interval.
    #[error("{field} must be within {min}..={max}, got {value}")]
    OutOfRange {
        /// Field name.
        field: String,
        /// Smallest allowed value.
        min: f64,
        /// Largest allowed value.
        max: f64,
        /// The offending value.
        value: f64,
    },
    /// A table value (sensitivity or power) is negative.
    #[error("{field} must be non-negative, got {value}")]
    Negative {
        /// Field name with index, e.g. `l[12]`.
        field: String,
        /// The offending value.
        value: f64,
    },
    /// A sampled table has too few samples.
    #[error("{field} needs at least {min} samples, got {got}")]
    TooFewSamples {
        /// Field name.
        field: String,
        /// Minimum number of samples.
        min: usize,
        /// Number given.
        got: usize,
    },
    /// A column of a sampled table differs in length from its wavelength column.
    #[error("{field} has {got} samples but wavelengths_nm has {expected}")]
    LengthMismatch {
        /// Field name.
        field: String,
        /// Length of `wavelengths_nm`.
        expected: usize,
        /// Length of the column.
        got: usize,
    },
    /// Wavelengths of a sampled table are not strictly increasing.
    #[error("{field} must be strictly increasing, but {value} follows {previous}")]
    NotIncreasing {
        /// Field name with index of the offending sample.
        field: String,
        /// The preceding wavelength.
        previous: f64,
        /// The offending wavelength.
        value: f64,
    },
    /// A sensitivity channel is zero everywhere on the 390..=830 nm grid.
    #[error("{field} must be positive somewhere within 390..=830 nm")]
    NoSensitivityOnGrid {
        /// Field name.
        field: String,
    },
    /// Too little of a projector's power falls on the 390..=830 nm grid to normalise it
    /// meaningfully.
    #[error(
        "{field}: only {:.3} % of the spectrum's power lies within 390..=830 nm, \
         at least {:.0} % is required",
        fraction * 100.0,
        MIN_POWER_FRACTION_ON_GRID * 100.0
    )]
    TooLittlePowerOnGrid {
        /// Field name.
        field: String,
        /// Fraction of the power that lies on the grid.
        fraction: f64,
    },
}

pub(crate) fn check_finite(field: &str, value: f64) -> Result<(), SpectralError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(SpectralError::NotFinite {
            field: field.to_owned(),
            value,
        })
    }
}

pub(crate) fn check_range(field: &str, value: f64, min: f64, max: f64) -> Result<(), SpectralError> {
    check_finite(field, value)?;
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(SpectralError::OutOfRange {
            field: field.to_owned(),
            min,
            max,
            value,
        })
    }
}
