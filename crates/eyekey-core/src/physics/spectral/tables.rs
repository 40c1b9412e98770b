//! Sampled spectral tables: validation, resampling onto the grid, integration.
use crate::physics::spectral::{check_finite, check_range, wavelengths_nm, SpectralError, WAVELENGTH_STEP_NM};

// Sampled tables

/// Wavelength bounds of user-supplied tables, in nm.
pub(crate) const TABLE_RANGE_NM: (f64, f64) = (360.0, 850.0);
/// Minimum number of samples of a user-supplied table.
pub(crate) const TABLE_MIN_SAMPLES: usize = 10;
/// A projector must put at least this fraction of its power on the grid: normalising a spectrum
/// that is almost entirely outside 390..=830 nm would blow its far tail up into a fictitious
/// visible band.
pub(crate) const MIN_POWER_FRACTION_ON_GRID: f64 = 0.01;

/// Checks a sampled table: at least 10 samples, equal column lengths, finite, wavelengths strictly
/// increasing within 360..=850 nm, values non-negative.
pub(crate) fn validate_table(wavelengths_nm: &[f64], columns: &[(&str, &[f64])]) -> Result<(), SpectralError> {
    if wavelengths_nm.len() < TABLE_MIN_SAMPLES {
        return Err(SpectralError::TooFewSamples {
            field: "wavelengths_nm".to_owned(),
            min: TABLE_MIN_SAMPLES,
            got: wavelengths_nm.len(),
        });
    }
    for (name, values) in columns {
        if values.len() != wavelengths_nm.len() {
            return Err(SpectralError::LengthMismatch {
                field: (*name).to_owned(),
                expected: wavelengths_nm.len(),
                got: values.len(),
            });
        }
    }
    for (i, &w) in wavelengths_nm.iter().enumerate() {
        let field = format!("wavelengths_nm[{i}]");
        check_range(&field, w, TABLE_RANGE_NM.0, TABLE_RANGE_NM.1)?;
        if i > 0 && w <= wavelengths_nm[i - 1] {
            return Err(SpectralError::NotIncreasing {
                field,
                previous: wavelengths_nm[i - 1],
                value: w,
            });
        }
    }
    for (name, values) in columns {
        for (i, &v) in values.iter().enumerate() {
            let field = format!("{name}[{i}]");
            check_finite(&field, v)?;
            if v < 0.0 {
                return Err(SpectralError::Negative { field, value: v });
            }
        }
    }
    Ok(())
}

/// Linear interpolation of a sampled table onto the spectral grid, 0 outside the table's wavelength
/// range. Does not panic on unvalidated input (mismatched lengths read missing values as 0).
pub(crate) fn resample_onto_grid(wavelengths: &[f64], values: &[f64]) -> Vec<f64> {
    let value = |i: usize| values.get(i).copied().unwrap_or(0.0);
    wavelengths_nm()
        .map(|lambda| {
            let (Some(&first), Some(&last)) = (wavelengths.first(), wavelengths.last()) else {
                return 0.0;
            };
            if !(first..=last).contains(&lambda) {
                return 0.0;
            }
            // First index with wavelength > λ: λ lies in [w[j-1], w[j]).
            let j = wavelengths.partition_point(|&w| w <= lambda);
            if j == 0 {
                return value(0);
            }
            if j >= wavelengths.len() {
                return value(wavelengths.len() - 1);
            }
            let (w0, w1) = (wavelengths[j - 1], wavelengths[j]);
            let frac = if w1 > w0 { (lambda - w0) / (w1 - w0) } else { 0.0 };
            value(j - 1) + frac * (value(j) - value(j - 1))
        })
        .collect()
}

/// Trapezoid integral of a sampled table over its own wavelength range.
pub(crate) fn trapezoid(wavelengths: &[f64], values: &[f64]) -> f64 {
    wavelengths
        .windows(2)
        .zip(values.windows(2))
        .map(|(w, v)| 0.5 * (v[0] + v[1]) * (w[1] - w[0]))
        .sum()
}

/// Rectangle-rule integral Σ_k v(λ_k)·Δλ over the spectral grid.
pub(crate) fn grid_integral(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() * WAVELENGTH_STEP_NM
}

/// One sample wavelength of a user-supplied table, nm (the schema of an item of a table's `wavelengths_nm`).
#[cfg(feature = "openapi")]
pub struct WavelengthSample(pub f64);

#[cfg(feature = "openapi")]
impl utoipa::PartialSchema for WavelengthSample {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        number_schema(
            Some(TABLE_RANGE_NM.0),
            Some(TABLE_RANGE_NM.1),
            "A sample wavelength, nm (360–850; the samples strictly increase)",
        )
    }
}

#[cfg(feature = "openapi")]
impl utoipa::ToSchema for WavelengthSample {}

/// One value of a user-supplied table's column: a sensitivity or a power, non-negative, any scale.
#[cfg(feature = "openapi")]
pub struct SampleValue(pub f64);

#[cfg(feature = "openapi")]
impl utoipa::PartialSchema for SampleValue {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        number_schema(
            Some(0.0),
            None,
            "A value at the sample of the same index (non-negative, any scale)",
        )
    }
}

#[cfg(feature = "openapi")]
impl utoipa::ToSchema for SampleValue {}

#[cfg(feature = "openapi")]
fn number_schema(
    minimum: Option<f64>,
    maximum: Option<f64>,
    description: &str,
) -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
    utoipa::openapi::ObjectBuilder::new()
        .schema_type(utoipa::openapi::schema::Type::Number)
        .format(Some(utoipa::openapi::SchemaFormat::KnownFormat(
            utoipa::openapi::KnownFormat::Double,
        )))
        .minimum(minimum)
        .maximum(maximum)
        .description(Some(description))
        .into()
}
