//! Spectral model of the viewer and the display (paper §3.1, Eqs. 1 and 12).
//!
//! * Cone fundamentals x̄_a(λ), a ∈ {L, M, S}: the Stockman & Sharpe (2000) 2° table (= CIE
//!   170-1:2006 LMS at age 32), and individual observers from the CIE 170-1:2006 physiological
//!   model extended with the eight parameters of Asano, Fairchild & Blondé (2016), "Individual
//!   Colorimetric Observer Model", PLoS ONE 11(2): e0145671.
//! * Projector spectra E_n(λ) and the coupling matrix c_na = ∫ E_n(λ) x̄_a(λ) dλ (Eq. 12), so that
//!   a light mix with projector intensities I_n stimulates cone a by S_a = Σ_n I_n c_na.
//! * Colour conversions between sRGB documents and LMS for the standard observer.
//!
//! Every spectrum lives on one wavelength grid: 390..=830 nm in 1-nm steps ([`wavelengths_nm`]),
//! the grid of the CIE 2006 tables. Cone fundamentals are energy-based (sensitivity per unit
//! radiant power) and each one is scaled to a peak of 1; the normalisation constant K of Eq. 1 is
//! absorbed into that scaling.

use std::sync::OnceLock;

use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// First wavelength of the spectral grid, in nm.
pub const WAVELENGTH_START_NM: f64 = 390.0;
/// Spacing of the spectral grid, in nm (the Δλ of every sum over wavelength in this module).
pub const WAVELENGTH_STEP_NM: f64 = 1.0;
/// Number of samples on the spectral grid: 390..=830 nm in 1-nm steps.
pub const N_WAVELENGTHS: usize = 441;

/// The wavelengths of the spectral grid in nm, ascending: 390, 391, …, 830.
pub fn wavelengths_nm() -> impl Iterator<Item = f64> {
    (0..N_WAVELENGTHS).map(|k| WAVELENGTH_START_NM + k as f64 * WAVELENGTH_STEP_NM)
}

// -------------------------------------------------------------------------------------------------
// Errors
// -------------------------------------------------------------------------------------------------

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

fn check_finite(field: &str, value: f64) -> Result<(), SpectralError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(SpectralError::NotFinite {
            field: field.to_owned(),
            value,
        })
    }
}

fn check_range(field: &str, value: f64, min: f64, max: f64) -> Result<(), SpectralError> {
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

// -------------------------------------------------------------------------------------------------
// Embedded reference data (parsed once)
// -------------------------------------------------------------------------------------------------

const SS_2DEG_CSV: &str = include_str!("../data/lms_stockman_sharpe_2000_2deg.csv");
const CIE2006_TEMPLATES_CSV: &str = include_str!("../data/cie2006_model_templates_1nm.csv");
const ASANO_JSON: &str = include_str!("../data/asano2016_individual_observer_params.json");

/// Parses one of the shipped 1-nm CSV tables: checks the header and that the first column is
/// exactly the spectral grid. Empty cells become `None`. The files are compiled in, so a malformed
/// file is a build defect (caught by the unit tests), not a run-time condition: it panics with the
/// reason.
fn parse_grid_csv(name: &str, text: &str, header: &str) -> Vec<Vec<Option<f64>>> {
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let found = lines.next().unwrap_or_default().trim();
    assert_eq!(found, header, "{name}: unexpected header");
    let n_cols = header.split(',').count();
    let rows: Vec<Vec<Option<f64>>> = lines
        .map(|line| {
            let cells: Vec<Option<f64>> = line
                .split(',')
                .map(|cell| {
                    let cell = cell.trim();
                    (!cell.is_empty()).then(|| {
                        cell.parse::<f64>()
                            .unwrap_or_else(|e| panic!("{name}: bad number {cell:?}: {e}"))
                    })
                })
                .collect();
            assert_eq!(cells.len(), n_cols, "{name}: wrong column count in {line:?}");
            cells
        })
        .collect();
    assert_eq!(rows.len(), N_WAVELENGTHS, "{name}: wrong row count");
    for (row, lambda) in rows.iter().zip(wavelengths_nm()) {
        assert_eq!(row[0], Some(lambda), "{name}: wavelength column is not the grid");
    }
    rows
}

fn column(name: &str, rows: &[Vec<Option<f64>>], col: usize) -> Vec<f64> {
    rows.iter()
        .map(|r| r[col].unwrap_or_else(|| panic!("{name}: missing value in column {col}")))
        .collect()
}

fn parse_lms_table(name: &str, text: &str) -> ConeFundamentals {
    let rows = parse_grid_csv(name, text, "wavelength_nm,l,m,s");
    ConeFundamentals {
        l: column(name, &rows, 1),
        m: column(name, &rows, 2),
        s: column(name, &rows, 3),
    }
}

/// Building blocks of the CIE 170-1:2006 physiological observer on the 1-nm grid (data/README.md
/// §2).
struct Cie2006Templates {
    /// log10 low-density absorbance A_i(λ) of the L, M, S photopigments, starting at 390 nm. L and
    /// M cover the grid; S stops at 615 nm, beyond which CIE 170-1 leaves it undefined.
    log10_absorbance: [Vec<f64>; 3],
    /// Macular pigment density relative to its peak (scaled by D_mac,max of the field size).
    d_macula_rel: Vec<f64>,
    /// Age-dependent part of the ocular-media density at age 32.
    d_ocul1_32: Vec<f64>,
    /// Age-independent part of the ocular-media density.
    d_ocul2: Vec<f64>,
}

fn cie2006_templates() -> &'static Cie2006Templates {
    static TEMPLATES: OnceLock<Cie2006Templates> = OnceLock::new();
    TEMPLATES.get_or_init(|| {
        let name = "cie2006_model_templates_1nm.csv";
        let rows = parse_grid_csv(
            name,
            CIE2006_TEMPLATES_CSV,
            concat!(
                "wavelength_nm,log10_abs_l,log10_abs_m,log10_abs_s,",
                "d_macula_2deg,d_macula_rel,d_ocul_32,d_ocul1_32,d_ocul2"
            ),
        );
        // The S template is a contiguous run from 390 nm followed by empty cells.
        let s: Vec<f64> = rows.iter().map_while(|r| r[3]).collect();
        assert!(
            rows[s.len()..].iter().all(|r| r[3].is_none()),
            "{name}: S template has a gap"
        );
        Cie2006Templates {
            log10_absorbance: [column(name, &rows, 1), column(name, &rows, 2), s],
            d_macula_rel: column(name, &rows, 5),
            d_ocul1_32: column(name, &rows, 7),
            d_ocul2: column(name, &rows, 8),
        }
    })
}

/// Standard deviations of the eight Asano et al. (2016) parameters.
#[derive(Debug, Deserialize)]
struct AsanoSds {
    od_lens_pct: f64,
    od_macula_pct: f64,
    #[serde(rename = "od_L_pct")]
    od_l_pct: f64,
    #[serde(rename = "od_M_pct")]
    od_m_pct: f64,
    #[serde(rename = "od_S_pct")]
    od_s_pct: f64,
    #[serde(rename = "shift_L_nm")]
    shift_l_nm: f64,
    #[serde(rename = "shift_M_nm")]
    shift_m_nm: f64,
    #[serde(rename = "shift_S_nm")]
    shift_s_nm: f64,
}

/// The "scaled" (step 2) SDs that Asano's model uses for populations: the literature SDs × 0.98
/// (lens, macula) and × 0.5 (the others), taken unrounded from the shipped JSON
/// (`sd_scaled_step2.values_exact`).
fn asano_scaled_sds() -> &'static AsanoSds {
    #[derive(Deserialize)]
    struct Scaled {
        values_exact: AsanoSds,
    }
    #[derive(Deserialize)]
    struct File {
        sd_scaled_step2: Scaled,
    }
    static SDS: OnceLock<AsanoSds> = OnceLock::new();
    SDS.get_or_init(|| {
        let file: File = serde_json::from_str(ASANO_JSON)
            .unwrap_or_else(|e| panic!("asano2016_individual_observer_params.json: {e}"));
        file.sd_scaled_step2.values_exact
    })
}

// -------------------------------------------------------------------------------------------------
// Cone fundamentals
// -------------------------------------------------------------------------------------------------

/// Cone fundamentals x̄_L, x̄_M, x̄_S (paper Eq. 1): energy-based (sensitivity per unit radiant
/// power), linear, sampled on the spectral grid ([`wavelengths_nm`]), each scaled to a peak of 1.
#[derive(Clone, Debug, PartialEq)]
pub struct ConeFundamentals {
    /// L-cone sensitivity, one value per grid wavelength.
    pub l: Vec<f64>,
    /// M-cone sensitivity, one value per grid wavelength.
    pub m: Vec<f64>,
    /// S-cone sensitivity, one value per grid wavelength (0 from 616 nm up, where it is not
    /// defined).
    pub s: Vec<f64>,
}

impl ConeFundamentals {
    fn channels(&self) -> [&[f64]; 3] {
        [&self.l, &self.m, &self.s]
    }
}

/// The Stockman & Sharpe (2000) 2° cone fundamentals (CVRL linss2_10e_1), adopted by CIE 170-1:2006
/// as its 2°, age-32 LMS: the shipped table `data/lms_stockman_sharpe_2000_2deg.csv`, unchanged.
/// Its grid maxima are 0.99998–0.99999 because the true peaks lie between samples.
pub fn stockman_sharpe_2deg() -> &'static ConeFundamentals {
    static TABLE: OnceLock<ConeFundamentals> = OnceLock::new();
    TABLE.get_or_init(|| parse_lms_table("lms_stockman_sharpe_2000_2deg.csv", SS_2DEG_CSV))
}

/// Physiological parameters of one observer: the CIE 170-1:2006 age and field size plus the eight
/// deviations of Asano et al. (2016). The default (age 32, 2° field, all deviations 0) is the CIE
/// 2006 2° standard observer, i.e. the Stockman & Sharpe 2° fundamentals.
///
/// In JSON every field is optional (missing fields take the default) and unknown fields are
/// rejected.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObserverParameters {
    /// Age in years; drives the ocular-media (lens) density, CIE 170-1 §5.
    pub age_years: f64,
    /// Angular diameter of the viewing field in degrees; drives the photopigment and macular
    /// densities.
    pub field_size_deg: f64,
    /// Deviation of the ocular-media density, in % of its age-dependent value: D_ocul · (1 +
    /// v/100).
    pub od_lens_pct: f64,
    /// Deviation of the peak macular pigment density, in %: D_mac,max · (1 + v/100).
    pub od_macula_pct: f64,
    /// Deviation of the L photopigment peak optical density, in %: D_max,L · (1 + v/100).
    pub od_l_pct: f64,
    /// Deviation of the M photopigment peak optical density, in %: D_max,M · (1 + v/100).
    pub od_m_pct: f64,
    /// Deviation of the S photopigment peak optical density, in %: D_max,S · (1 + v/100).
    pub od_s_pct: f64,
    /// Shift of the L absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    pub shift_l_nm: f64,
    /// Shift of the M absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    pub shift_m_nm: f64,
    /// Shift of the S absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    pub shift_s_nm: f64,
}

impl Default for ObserverParameters {
    fn default() -> Self {
        Self {
            age_years: 32.0,
            field_size_deg: 2.0,
            od_lens_pct: 0.0,
            od_macula_pct: 0.0,
            od_l_pct: 0.0,
            od_m_pct: 0.0,
            od_s_pct: 0.0,
            shift_l_nm: 0.0,
            shift_m_nm: 0.0,
            shift_s_nm: 0.0,
        }
    }
}

/// Allowed ranges of [`ObserverParameters`]. Age and field extend the CIE 170-1 ranges (20–80
/// years, 1–10°) downwards/upwards by extrapolating its formulas; the density and shift bounds are
/// far outside any population (Asano SDs ≤ 37 % and ≤ 2 nm) and only keep the model physical.
const AGE_RANGE_YEARS: (f64, f64) = (10.0, 90.0);
const FIELD_RANGE_DEG: (f64, f64) = (1.0, 10.0);
const DENSITY_PCT_RANGE: (f64, f64) = (-100.0, 300.0);
const SHIFT_RANGE_NM: (f64, f64) = (-15.0, 15.0);

/// Rounds a field-size-dependent density to 3 decimals (half away from zero), as the CIE TC1-97
/// reference implementation of CIE 170-1:2006 does. The official 2° and 10° tables were computed
/// this way: without the rounding the 10° fundamentals are off by 1.3e-4 instead of 7e-5.
fn round_3_decimals(density: f64) -> f64 {
    (density * 1000.0).round() / 1000.0
}

/// CIE 170-1:2006 peak optical density of the L and M photopigments for a field of `field_deg`
/// degrees.
fn d_max_lm(field_deg: f64) -> f64 {
    round_3_decimals(0.38 + 0.54 * (-field_deg / 1.333).exp())
}

/// CIE 170-1:2006 peak optical density of the S photopigment for a field of `field_deg` degrees.
fn d_max_s(field_deg: f64) -> f64 {
    round_3_decimals(0.30 + 0.45 * (-field_deg / 1.333).exp())
}

/// CIE 170-1:2006 peak macular pigment density for a field of `field_deg` degrees.
fn d_mac_max(field_deg: f64) -> f64 {
    round_3_decimals(0.485 * (-field_deg / 6.132).exp())
}

/// CIE 170-1:2006 age factor of the age-dependent ocular-media density: D_ocul = d_ocul1·factor +
/// d_ocul2.
fn lens_age_factor(age_years: f64) -> f64 {
    if age_years <= 60.0 {
        1.0 + 0.02 * (age_years - 32.0)
    } else {
        1.56 + 0.0667 * (age_years - 60.0)
    }
}

/// Evaluates a log10 absorbance template (1-nm samples from 390 nm) at `x_nm` by linear
/// interpolation. Below 390 nm the first segment is extended linearly (log absorbance is smooth and
/// nearly straight there); above the last sample it is extended the same way if `extend_long` (L,
/// M), otherwise the template is undefined and `None` is returned (S above 615 nm).
fn template_at(values: &[f64], x_nm: f64, extend_long: bool) -> Option<f64> {
    let n = values.len();
    if n < 2 {
        return None;
    }
    let t = (x_nm - WAVELENGTH_START_NM) / WAVELENGTH_STEP_NM;
    let last = (n - 1) as f64;
    if t > last && !extend_long {
        return None;
    }
    let i = (t.floor().max(0.0) as usize).min(n - 2);
    let frac = t - i as f64;
    Some(values[i] + frac * (values[i + 1] - values[i]))
}

impl ObserverParameters {
    /// Checks that every parameter is finite and in range: age 10..=90 years, field 1..=10°,
    /// density deviations −100..=300 %, shifts −15..=15 nm. The error names the field, e.g.
    /// "age_years must be within 10..=90, got 120".
    pub fn validate(&self) -> Result<(), SpectralError> {
        check_range("age_years", self.age_years, AGE_RANGE_YEARS.0, AGE_RANGE_YEARS.1)?;
        check_range(
            "field_size_deg",
            self.field_size_deg,
            FIELD_RANGE_DEG.0,
            FIELD_RANGE_DEG.1,
        )?;
        for (field, value) in [
            ("od_lens_pct", self.od_lens_pct),
            ("od_macula_pct", self.od_macula_pct),
            ("od_l_pct", self.od_l_pct),
            ("od_m_pct", self.od_m_pct),
            ("od_s_pct", self.od_s_pct),
        ] {
            check_range(field, value, DENSITY_PCT_RANGE.0, DENSITY_PCT_RANGE.1)?;
        }
        for (field, value) in [
            ("shift_l_nm", self.shift_l_nm),
            ("shift_m_nm", self.shift_m_nm),
            ("shift_s_nm", self.shift_s_nm),
        ] {
            check_range(field, value, SHIFT_RANGE_NM.0, SHIFT_RANGE_NM.1)?;
        }
        Ok(())
    }

    /// Energy-based cone fundamentals of this observer on the spectral grid, each normalised to a
    /// grid peak of 1, from the CIE 170-1:2006 physiological model with the Asano et al. (2016)
    /// deviations:
    ///
    /// * photopigment peak densities D_max,L = D_max,M = 0.38 + 0.54·e^(−f/1.333), D_max,S = 0.30 +
    ///   0.45·e^(−f/1.333), each × (1 + od_i/100);
    /// * macular density D_mac,max·d_mac,rel(λ) with D_mac,max = 0.485·e^(−f/6.132) × (1 +
    ///   od_macula/100). Like the CIE TC1-97 reference code, the three field-size formulas are
    ///   rounded to 3 decimals before the deviations are applied; this is how the official tables
    ///   were made (it halves the difference to the 10° table) and makes the field-size dependence
    ///   step in units of 0.001 density;
    /// * ocular media D_ocul = [d_ocul1(λ)·(1 + 0.02(A − 32)) + d_ocul2(λ)] for A ≤ 60, and with
    ///   1.56 + 0.0667(A − 60) as the factor for A > 60, × (1 + od_lens/100);
    /// * absorbance templates shifted along λ: A_i'(λ) = A_i(λ − shift_i), linearly interpolated on
    ///   the 1-nm table, and extended linearly beyond its ends (below 390 nm; above 830 nm for L
    ///   and M). S is 0 wherever λ − shift_S > 615 nm, where CIE 170-1 leaves the S template
    ///   undefined;
    /// * absorptance α_i = 1 − 10^(−D_max,i·10^A_i'), quantal q_i = α_i·10^(−D_mac − D_ocul),
    ///   energy e_i = λ·q_i, scaled to a peak of 1 on the grid.
    ///
    /// CIE 170-1 defines the age formula for 20–80 years only. Ages 10–20 and 80–90 (accepted by
    /// [`validate`](Self::validate)) extrapolate the same linear formulas; treat them as
    /// approximate.
    ///
    /// Call [`validate`](Self::validate) first: out-of-range input does not panic but may give
    /// meaningless (e.g. all-zero or non-finite) fundamentals.
    pub fn cone_fundamentals(&self) -> ConeFundamentals {
        let t = cie2006_templates();
        let f = self.field_size_deg;
        let scale = |pct: f64| 1.0 + pct / 100.0;
        let d_max = [
            d_max_lm(f) * scale(self.od_l_pct),
            d_max_lm(f) * scale(self.od_m_pct),
            d_max_s(f) * scale(self.od_s_pct),
        ];
        let shift = [self.shift_l_nm, self.shift_m_nm, self.shift_s_nm];
        let d_mac = d_mac_max(f) * scale(self.od_macula_pct);
        let age_factor = lens_age_factor(self.age_years);
        let lens_scale = scale(self.od_lens_pct);

        let mut channels: [Vec<f64>; 3] = std::array::from_fn(|_| Vec::with_capacity(N_WAVELENGTHS));
        for (k, lambda) in wavelengths_nm().enumerate() {
            let d_ocul = (t.d_ocul1_32[k] * age_factor + t.d_ocul2[k]) * lens_scale;
            let prereceptoral = 10f64.powf(-d_mac * t.d_macula_rel[k] - d_ocul);
            for (i, channel) in channels.iter_mut().enumerate() {
                let extend_long = i != 2;
                let e = match template_at(&t.log10_absorbance[i], lambda - shift[i], extend_long) {
                    Some(log_abs) => {
                        let absorptance = 1.0 - 10f64.powf(-d_max[i] * 10f64.powf(log_abs));
                        lambda * absorptance * prereceptoral
                    }
                    None => 0.0,
                };
                channel.push(e);
            }
        }
        for channel in &mut channels {
            normalise_peak(channel);
        }
        let [l, m, s] = channels;
        ConeFundamentals { l, m, s }
    }
}

/// Scales `values` so that their maximum is 1; leaves them alone if the maximum is not positive and
/// finite.
fn normalise_peak(values: &mut [f64]) {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max > 0.0 && max.is_finite() {
        values.iter_mut().for_each(|v| *v /= max);
    }
}

/// Draws one observer from the Asano et al. (2016) population model: each of the eight deviations
/// is normal with mean 0 and the "scaled step 2" SD of the shipped JSON (lens 18.7 %, macula 36.5
/// %, L/M densities 9.0 %, S density 7.4 %, shifts 2.0 / 1.5 / 1.25 nm); density deviations are
/// clipped at −100 % (zero density), as in Asano's code.
///
/// Age: Asano draws it from the US Census 2010 distribution restricted to 10–70 years. eyekey ships
/// no census table and the CIE 2006 age formula is only defined from 20 years, so the age is drawn
/// uniformly from 20..=70 years instead. The field size is 2°.
///
/// The result always passes [`ObserverParameters::validate`]: densities are also capped at +300 %
/// and shifts at ±15 nm, bounds more than 8 SD out that a sample practically never reaches.
pub fn sample_observer_parameters<R: Rng + ?Sized>(rng: &mut R) -> ObserverParameters {
    let sd = asano_scaled_sds();
    let mut normal = |sd: f64| -> f64 { rng.sample::<f64, _>(StandardNormal) * sd };
    let density = |v: f64| v.clamp(DENSITY_PCT_RANGE.0, DENSITY_PCT_RANGE.1);
    let shift = |v: f64| v.clamp(SHIFT_RANGE_NM.0, SHIFT_RANGE_NM.1);
    let od_lens_pct = density(normal(sd.od_lens_pct));
    let od_macula_pct = density(normal(sd.od_macula_pct));
    let od_l_pct = density(normal(sd.od_l_pct));
    let od_m_pct = density(normal(sd.od_m_pct));
    let od_s_pct = density(normal(sd.od_s_pct));
    let shift_l_nm = shift(normal(sd.shift_l_nm));
    let shift_m_nm = shift(normal(sd.shift_m_nm));
    let shift_s_nm = shift(normal(sd.shift_s_nm));
    ObserverParameters {
        age_years: rng.gen_range(20.0..=70.0),
        field_size_deg: 2.0,
        od_lens_pct,
        od_macula_pct,
        od_l_pct,
        od_m_pct,
        od_s_pct,
        shift_l_nm,
        shift_m_nm,
        shift_s_nm,
    }
}

// -------------------------------------------------------------------------------------------------
// Sampled tables
// -------------------------------------------------------------------------------------------------

/// Wavelength bounds of user-supplied tables, in nm.
const TABLE_RANGE_NM: (f64, f64) = (360.0, 850.0);
/// Minimum number of samples of a user-supplied table.
const TABLE_MIN_SAMPLES: usize = 10;
/// A projector must put at least this fraction of its power on the grid: normalising a spectrum
/// that is almost entirely outside 390..=830 nm would blow its far tail up into a fictitious
/// visible band.
const MIN_POWER_FRACTION_ON_GRID: f64 = 0.01;

/// Checks a sampled table: at least 10 samples, equal column lengths, finite, wavelengths strictly
/// increasing within 360..=850 nm, values non-negative.
fn validate_table(wavelengths_nm: &[f64], columns: &[(&str, &[f64])]) -> Result<(), SpectralError> {
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
fn resample_onto_grid(wavelengths: &[f64], values: &[f64]) -> Vec<f64> {
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
fn trapezoid(wavelengths: &[f64], values: &[f64]) -> f64 {
    wavelengths
        .windows(2)
        .zip(values.windows(2))
        .map(|(w, v)| 0.5 * (v[0] + v[1]) * (w[1] - w[0]))
        .sum()
}

/// Rectangle-rule integral Σ_k v(λ_k)·Δλ over the spectral grid.
fn grid_integral(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() * WAVELENGTH_STEP_NM
}

// -------------------------------------------------------------------------------------------------
// Spectral sensitivity of a viewer
// -------------------------------------------------------------------------------------------------

/// How a viewer's cone fundamentals are given: by physiological parameters (CIE 2006 + Asano 2016)
/// or by a measured table.
///
/// JSON: `{"kind": "parameters", "age_years": 45, "shift_l_nm": 1.5}` (missing parameters take the
/// standard observer's values) or `{"kind": "table", "wavelengths_nm": [...], "l": [...], "m":
/// [...], "s": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SpectralSensitivity {
    /// Individual-observer parameters.
    Parameters(ObserverParameters),
    /// Measured cone fundamentals (energy-based, linear; any scale, they are peak-normalised on
    /// use).
    Table {
        /// Sample wavelengths in nm, strictly increasing, within 360..=850.
        wavelengths_nm: Vec<f64>,
        /// L-cone sensitivity at each wavelength.
        l: Vec<f64>,
        /// M-cone sensitivity at each wavelength.
        m: Vec<f64>,
        /// S-cone sensitivity at each wavelength.
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

// -------------------------------------------------------------------------------------------------
// Projectors and the coupling matrix (Eq. 12)
// -------------------------------------------------------------------------------------------------

/// Spectral power distribution E_n(λ) of one projector band of the multiband display (paper §5.1,
/// Fig. 9). Only the shape matters: [`power_on_grid`](Self::power_on_grid) normalises it to unit
/// radiant power.
///
/// JSON: `{"kind": "gaussian", "centre_nm": 450, "fwhm_nm": 20}` or `{"kind": "sampled",
/// "wavelengths_nm": [...], "power": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProjectorSpectrum {
    /// A Gaussian band, a good model of a projector behind a narrow band-pass filter.
    Gaussian {
        /// Centre wavelength in nm, 380..=780.
        centre_nm: f64,
        /// Full width at half maximum in nm, 1..=200.
        fwhm_nm: f64,
    },
    /// A measured spectrum (any scale), interpolated linearly, 0 outside its range.
    Sampled {
        /// Sample wavelengths in nm, strictly increasing, within 360..=850.
        wavelengths_nm: Vec<f64>,
        /// Spectral power at each wavelength (non-negative).
        power: Vec<f64>,
    },
}

/// Gaussian evaluated on the grid (unnormalised, peak 1) and its standard deviation in nm.
fn gaussian_on_grid(centre_nm: f64, fwhm_nm: f64) -> (Vec<f64>, f64) {
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
/// use eyekey::spectral::{coupling, paper_projectors, stockman_sharpe_2deg};
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

// -------------------------------------------------------------------------------------------------
// Colour: sRGB ⇄ linear ⇄ XYZ ⇄ LMS
// -------------------------------------------------------------------------------------------------

type Mat3 = [[f64; 3]; 3];

/// Linear sRGB → CIE XYZ (D65), IEC 61966-2-1:1999 §5.2.
const SRGB_TO_XYZ: Mat3 = [
    [0.4124, 0.3576, 0.1805],
    [0.2126, 0.7152, 0.0722],
    [0.0193, 0.1192, 0.9505],
];

/// Stockman–Sharpe 2° LMS → CIE 2012 2° XYZ (CIE 170-2:2015): XYZ = M·LMS, reproducing the CIE 2012
/// table to 1.9e-6 (data/README.md §1).
const LMS_TO_XYZ_2012: Mat3 = [
    [1.94735469, -1.41445123, 0.36476327],
    [0.68990272, 0.34832189, 0.0],
    [0.0, 0.0, 1.93485343],
];

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

fn mat_vec(a: &Mat3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

/// Inverse of a well-conditioned constant 3×3 matrix (adjugate / determinant).
fn mat_inverse(a: &Mat3) -> Mat3 {
    let cof = |r0: usize, r1: usize, c0: usize, c1: usize| a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0];
    let adj = [
        [cof(1, 2, 1, 2), -cof(0, 2, 1, 2), cof(0, 1, 1, 2)],
        [-cof(1, 2, 0, 2), cof(0, 2, 0, 2), -cof(0, 1, 0, 2)],
        [cof(1, 2, 0, 1), -cof(0, 2, 0, 1), cof(0, 1, 0, 1)],
    ];
    let det = a[0][0] * adj[0][0] + a[0][1] * adj[1][0] + a[0][2] * adj[2][0];
    adj.map(|row| row.map(|v| v / det))
}

/// (linear sRGB → LMS, LMS → linear sRGB), computed once. The inverse directions are exact matrix
/// inverses (not the rounded inverse printed in IEC 61966-2-1) so that round trips are exact to
/// rounding error.
fn colour_matrices() -> &'static (Mat3, Mat3) {
    static MATRICES: OnceLock<(Mat3, Mat3)> = OnceLock::new();
    MATRICES.get_or_init(|| {
        let rgb_to_lms = mat_mul(&mat_inverse(&LMS_TO_XYZ_2012), &SRGB_TO_XYZ);
        let lms_to_rgb = mat_mul(&mat_inverse(&SRGB_TO_XYZ), &LMS_TO_XYZ_2012);
        (rgb_to_lms, lms_to_rgb)
    })
}

/// sRGB transfer function, encoded value → linear light (IEC 61966-2-1): v/12.92 for v ≤ 0.04045,
/// else ((v + 0.055)/1.055)^2.4. Negative inputs are mapped odd-symmetrically (−f(−v)) so that
/// out-of-gamut values survive a round trip; clamp to 0..=1 before writing pixels.
pub fn srgb_to_linear(v: f64) -> f64 {
    if v < 0.0 {
        return -srgb_to_linear(-v);
    }
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Inverse sRGB transfer function, linear light → encoded value (IEC 61966-2-1): 12.92·v for v ≤
/// 0.0031308, else 1.055·v^(1/2.4) − 0.055; odd-symmetric for negative inputs like
/// [`srgb_to_linear`].
pub fn linear_to_srgb(v: f64) -> f64 {
    if v < 0.0 {
        return -linear_to_srgb(-v);
    }
    if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Linear sRGB → LMS of the standard observer (Stockman–Sharpe 2°, peak-normalised fundamentals):
/// linear sRGB → XYZ with the IEC 61966-2-1 matrix (D65), then XYZ → LMS with the inverse of the
/// CIE 2012 matrix (XYZ = M·LMS, CIE 170-2:2015).
///
/// This is an approximation: the sRGB matrix is defined against CIE 1931 XYZ, whereas M belongs to
/// the CIE 2012 physiologically-relevant XYZ, so the LMS of a displayed colour is exact only for a
/// display whose primaries are metameric for both observers. The error is a small, smooth colour
/// shift (white maps close to, not exactly on, the LMS of D65), acceptable for turning documents
/// into target stimuli and simulated views back into images.
///
/// ```
/// use eyekey::spectral::{linear_srgb_to_lms, lms_to_linear_srgb};
/// let rgb = [0.2, 0.5, 0.9];
/// let back = lms_to_linear_srgb(linear_srgb_to_lms(rgb));
/// assert!((0..3).all(|i| (back[i] - rgb[i]).abs() < 1e-12));
/// ```
pub fn linear_srgb_to_lms(rgb: [f64; 3]) -> [f64; 3] {
    mat_vec(&colour_matrices().0, rgb)
}

/// LMS of the standard observer → linear sRGB, the exact inverse of [`linear_srgb_to_lms`] (same
/// approximation). The result may lie outside 0..=1 for colours outside the sRGB gamut.
pub fn lms_to_linear_srgb(lms: [f64; 3]) -> [f64; 3] {
    mat_vec(&colour_matrices().1, lms)
}

/// LMS of sRGB white (1, 1, 1) for the standard observer: the scale of a document's LMS image.
pub fn srgb_white_lms() -> [f64; 3] {
    linear_srgb_to_lms([1.0; 3])
}

// -------------------------------------------------------------------------------------------------
// Tests
// -------------------------------------------------------------------------------------------------

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    fn ss_10deg() -> ConeFundamentals {
        parse_lms_table(
            "lms_stockman_sharpe_2000_10deg.csv",
            include_str!("../data/lms_stockman_sharpe_2000_10deg.csv"),
        )
    }

    /// Largest absolute difference over all three channels, and where it occurs (nm).
    fn max_abs_diff(a: &ConeFundamentals, b: &ConeFundamentals) -> (f64, f64) {
        let mut worst = (0.0, 0.0);
        for (ca, cb) in a.channels().into_iter().zip(b.channels()) {
            assert_eq!(ca.len(), cb.len());
            for ((x, y), lambda) in ca.iter().zip(cb).zip(wavelengths_nm()) {
                let d = (x - y).abs();
                if d > worst.0 {
                    worst = (d, lambda);
                }
            }
        }
        worst
    }

    fn argmax(values: &[f64]) -> usize {
        values
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| i)
            .unwrap()
    }

    /// Wavelength of the peak, refined by a parabola through the grid maximum and its neighbours.
    fn peak_nm(values: &[f64]) -> f64 {
        let i = argmax(values);
        let (a, b, c) = (values[i - 1], values[i], values[i + 1]);
        WAVELENGTH_START_NM + i as f64 + 0.5 * (a - c) / (a - 2.0 * b + c)
    }

    #[test]
    fn shipped_tables_parse_onto_the_grid() {
        // Exact: the parser must keep every row of the 441-row files.
        let ss = stockman_sharpe_2deg();
        assert_eq!(wavelengths_nm().count(), N_WAVELENGTHS);
        assert_eq!(wavelengths_nm().last(), Some(830.0));
        for channel in ss.channels() {
            assert_eq!(channel.len(), N_WAVELENGTHS);
        }
        let t = cie2006_templates();
        // data/README.md §2: the S template is defined up to 615 nm only.
        assert_eq!(t.log10_absorbance[2].len(), 615 - 390 + 1);
        // README §1: S is exactly 0 from 616 nm up.
        assert!(ss.s[616 - 390..].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn standard_observer_reproduces_stockman_sharpe_2deg() {
        // ≤ 3e-4: data/README.md measured 2.6e-4, mostly at 551–559 nm where the official table
        // keeps a small macular tail that the CIE 2006 template sets to 0.
        let model = ObserverParameters::default().cone_fundamentals();
        let (diff, at_nm) = max_abs_diff(&model, stockman_sharpe_2deg());
        println!("2 deg: max abs diff {diff:.3e} at {at_nm} nm");
        assert!(diff <= 3e-4, "max abs diff {diff} at {at_nm} nm");
    }

    #[test]
    fn ten_degree_field_reproduces_stockman_sharpe_10deg() {
        // ≤ 1e-4: data/README.md measured 7.1e-5 for the same model at 10°.
        let params = ObserverParameters {
            field_size_deg: 10.0,
            ..Default::default()
        };
        let (diff, at_nm) = max_abs_diff(&params.cone_fundamentals(), &ss_10deg());
        println!("10 deg: max abs diff {diff:.3e} at {at_nm} nm");
        assert!(diff <= 1e-4, "max abs diff {diff} at {at_nm} nm");
    }

    #[test]
    fn older_lens_absorbs_more_short_wavelength_light() {
        // Strict inequality with a margin of 0.01: the lens density at 420 nm rises by ~60 % from
        // 32 to 70 years (CIE 170-1 age formula), a large effect on S relative to its peak.
        let at_420 = |age_years: f64| {
            let s = ObserverParameters {
                age_years,
                ..Default::default()
            }
            .cone_fundamentals()
            .s;
            s[420 - 390]
        };
        let (young, old) = (at_420(32.0), at_420(70.0));
        assert!(old < young - 0.01, "S(420) age 70 {old} vs age 32 {young}");
    }

    #[test]
    fn l_shift_moves_the_l_peak() {
        // ±1 nm: the shift is applied to the absorbance, while the prereceptoral filters and
        // self-screening stay put, so the energy peak moves by approximately, not exactly, the
        // shift.
        let base = peak_nm(&ObserverParameters::default().cone_fundamentals().l);
        let shifted = ObserverParameters {
            shift_l_nm: 5.0,
            ..Default::default()
        }
        .cone_fundamentals();
        let moved = peak_nm(&shifted.l) - base;
        println!("L peak moved by {moved:.3} nm");
        assert!((moved - 5.0).abs() <= 1.0, "L peak moved by {moved} nm");
        // M is untouched by an L shift (exact: same arithmetic).
        assert_eq!(shifted.m, ObserverParameters::default().cone_fundamentals().m);
    }

    #[test]
    fn s_shift_keeps_s_zero_where_the_template_is_undefined() {
        // Exact zeros: CIE 170-1 gives no S template above 615 nm, so λ − shift > 615 must give 0.
        for shift_s_nm in [-3.5, 2.0] {
            let s = ObserverParameters {
                shift_s_nm,
                ..Default::default()
            }
            .cone_fundamentals()
            .s;
            let first_zero = wavelengths_nm().position(|lambda| lambda - shift_s_nm > 615.0).unwrap();
            assert!(s[first_zero..].iter().all(|&v| v == 0.0));
            assert!(s[first_zero - 1] > 0.0);
            assert!(s.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn every_observer_fundamental_is_peak_normalised() {
        // 1e-12: normalisation divides by the grid maximum, so the maximum is 1 up to rounding.
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..20 {
            let cones = sample_observer_parameters(&mut rng).cone_fundamentals();
            for channel in cones.channels() {
                let max = channel.iter().copied().fold(0.0, f64::max);
                assert!((max - 1.0).abs() < 1e-12);
                assert!(channel.iter().all(|&v| (0.0..=1.0).contains(&v)));
            }
        }
    }

    #[test]
    fn extreme_valid_parameters_give_finite_fundamentals() {
        // Finite and peak 1: the validated corners of the parameter box must not break the model.
        for (age_years, field_size_deg, pct, shift) in [(10.0, 1.0, -100.0, -15.0), (90.0, 10.0, 300.0, 15.0)] {
            let p = ObserverParameters {
                age_years,
                field_size_deg,
                od_lens_pct: pct,
                od_macula_pct: pct,
                od_l_pct: pct.max(-99.0),
                od_m_pct: pct.max(-99.0),
                od_s_pct: pct.max(-99.0),
                shift_l_nm: shift,
                shift_m_nm: shift,
                shift_s_nm: shift,
            };
            p.validate().unwrap();
            for channel in p.cone_fundamentals().channels() {
                assert!(channel.iter().all(|v| v.is_finite()));
                let max = channel.iter().copied().fold(0.0, f64::max);
                assert!((max - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn asano_categorical_observers_validate() {
        // The ten categorical observers shipped with Asano's model are realistic individuals: they
        // must pass validation and give finite fundamentals.
        let json: serde_json::Value = serde_json::from_str(ASANO_JSON).unwrap();
        let cat = &json["categorical_observers"];
        let get = |key: &str, i: usize| cat[key][i].as_f64().unwrap();
        for i in 0..10 {
            let p = ObserverParameters {
                age_years: get("age_years", i),
                field_size_deg: 2.0,
                od_lens_pct: get("od_lens_pct", i),
                od_macula_pct: get("od_macula_pct", i),
                od_l_pct: get("od_L_pct", i),
                od_m_pct: get("od_M_pct", i),
                od_s_pct: get("od_S_pct", i),
                shift_l_nm: get("shift_L_nm", i),
                shift_m_nm: get("shift_M_nm", i),
                shift_s_nm: get("shift_S_nm", i),
            };
            p.validate().unwrap();
            let cones = p.cone_fundamentals();
            assert!(cones.channels().iter().all(|c| c.iter().all(|v| v.is_finite())));
        }
    }

    /// Simpson's rule on [a, b] with n (even) intervals.
    fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
        assert!(n % 2 == 0);
        let h = (b - a) / n as f64;
        let inner: f64 = (1..n)
            .map(|i| f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 })
            .sum();
        (f(a) + inner + f(b)) * h / 3.0
    }

    /// Linear interpolation of a grid-sampled channel at any λ within the grid.
    fn interp_grid(values: &[f64], lambda: f64) -> f64 {
        let t = (lambda - WAVELENGTH_START_NM) / WAVELENGTH_STEP_NM;
        let i = (t.floor() as usize).min(N_WAVELENGTHS - 2);
        values[i] + (t - i as f64) * (values[i + 1] - values[i])
    }

    #[test]
    fn coupling_matches_independent_integration() {
        // 1e-3 relative to each row's largest coefficient (entries like S at 640 nm are ~0, so a
        // per-entry relative error is meaningless): Simpson on a 0.1-nm grid of the analytic
        // Gaussian against linearly interpolated fundamentals differs from the 1-nm rectangle rule
        // only by interpolation error.
        let cones = stockman_sharpe_2deg();
        let projectors: Vec<ProjectorSpectrum> = [(450.0, 20.0), (520.0, 10.0), (590.0, 40.0), (640.0, 20.0)]
            .into_iter()
            .map(|(centre_nm, fwhm_nm)| ProjectorSpectrum::Gaussian { centre_nm, fwhm_nm })
            .collect();
        let c = coupling(&projectors, cones);
        assert_eq!(c.n_bands(), 4);
        for (projector, row) in projectors.iter().zip(&c.c) {
            let ProjectorSpectrum::Gaussian { centre_nm, fwhm_nm } = *projector else {
                unreachable!()
            };
            let sigma = fwhm_nm / (2.0 * (2.0 * 2f64.ln()).sqrt());
            let g = |l: f64| (-0.5 * ((l - centre_nm) / sigma).powi(2)).exp();
            let norm = simpson(g, 390.0, 830.0, 4400);
            let expected = cones
                .channels()
                .map(|x| simpson(|l| g(l) * interp_grid(x, l), 390.0, 830.0, 4400) / norm);
            let scale = expected.iter().copied().fold(0.0, f64::max);
            for a in 0..3 {
                let rel = (row[a] - expected[a]).abs() / scale;
                println!("{projector:?} channel {a}: relative difference {rel:.2e}");
                assert!(
                    rel < 1e-3,
                    "{projector:?} channel {a}: {} vs {} ({rel:e})",
                    row[a],
                    expected[a]
                );
            }
        }
    }

    #[test]
    fn narrow_gaussian_samples_the_fundamentals() {
        // 2 %: a 1-nm FWHM band still leaks ~6 % of its power to 549 and 551 nm, where the
        // fundamentals differ from 550 nm only by their (small) curvature.
        let cones = stockman_sharpe_2deg();
        let c = coupling(
            &[ProjectorSpectrum::Gaussian {
                centre_nm: 550.0,
                fwhm_nm: 1.0,
            }],
            cones,
        );
        let k = 550 - 390;
        for (a, x) in cones.channels().into_iter().enumerate() {
            let rel = (c.c[0][a] - x[k]).abs() / x[k];
            assert!(rel < 0.02, "channel {a}: {} vs {}", c.c[0][a], x[k]);
        }
    }

    #[test]
    fn projector_power_is_normalised_and_white_is_the_row_sum() {
        // 1e-12: both are sums of a few hundred terms.
        let projectors = paper_projectors();
        for p in &projectors {
            p.validate().unwrap();
            assert!((grid_integral(&p.power_on_grid()) - 1.0).abs() < 1e-12);
        }
        let sampled = ProjectorSpectrum::Sampled {
            wavelengths_nm: (0..20).map(|i| 500.0 + 2.5 * i as f64).collect(),
            power: (0..20).map(|i| 3.0 + i as f64).collect(),
        };
        sampled.validate().unwrap();
        assert!((grid_integral(&sampled.power_on_grid()) - 1.0).abs() < 1e-12);

        let c = coupling(&projectors, stockman_sharpe_2deg());
        let white = c.white_lms();
        for a in 0..3 {
            let sum: f64 = c.c.iter().map(|row| row[a]).sum();
            assert!((white[a] - sum).abs() < 1e-12);
        }
    }

    #[test]
    fn paper_projectors_can_mix_srgb_white() {
        // Non-negative weights (> 0.01 of the largest): the 450/520/640 nm bands must reach the
        // direction of sRGB white, otherwise the display cannot show a white page to the standard
        // observer.
        let c = coupling(&paper_projectors(), stockman_sharpe_2deg());
        let basis: Mat3 = std::array::from_fn(|a| [c.c[0][a], c.c[1][a], c.c[3][a]]);
        let w = mat_vec(&mat_inverse(&basis), srgb_white_lms());
        let max = w.iter().copied().fold(0.0, f64::max);
        assert!(w.iter().all(|&v| v > 0.01 * max), "weights {w:?}");
    }

    #[test]
    fn srgb_lms_round_trips() {
        // 1e-9 (the contract); the matrices are exact inverses, so the error is ~1e-15.
        let mut rng = StdRng::seed_from_u64(1);
        for _ in 0..1000 {
            let rgb: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-0.2..1.2));
            let back = lms_to_linear_srgb(linear_srgb_to_lms(rgb));
            let lms: [f64; 3] = std::array::from_fn(|_| rng.gen_range(0.0..1.0));
            let lms_back = linear_srgb_to_lms(lms_to_linear_srgb(lms));
            for i in 0..3 {
                assert!((back[i] - rgb[i]).abs() < 1e-9);
                assert!((lms_back[i] - lms[i]).abs() < 1e-9);
            }
            let v = rgb[0];
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-9);
            assert!((srgb_to_linear(linear_to_srgb(v)) - v).abs() < 1e-9);
        }
    }

    #[test]
    fn srgb_white_is_a_positive_lms() {
        // > 0.1: D65 white stimulates all three cone classes strongly; the bound only excludes a
        // broken matrix.
        let white = srgb_white_lms();
        println!("sRGB white LMS {white:?}");
        assert!(white.iter().all(|&v| v > 0.1), "{white:?}");
        // Y of white is 1 (IEC 61966-2-1 normalisation): Y = M[1]·LMS, exact to rounding of the
        // 4-digit matrix.
        let y = mat_vec(&LMS_TO_XYZ_2012, white)[1];
        assert!((y - 1.0).abs() < 1e-3, "Y = {y}");
    }

    #[test]
    fn srgb_transfer_function_at_known_points() {
        // Reference values from IEC 61966-2-1 (and their standard decimal expansions), to 1e-5.
        assert!((srgb_to_linear(0.5) - 0.214_04).abs() < 1e-5);
        assert!((srgb_to_linear(0.04045) - 0.04045 / 12.92).abs() < 1e-12);
        assert!((srgb_to_linear(0.04045) - 0.003_130_8).abs() < 1e-5);
        assert!((linear_to_srgb(0.003_130_8) - 0.04045).abs() < 1e-5);
        assert!((linear_to_srgb(0.214_04) - 0.5).abs() < 1e-5);
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-12);
        assert!((linear_to_srgb(1.0) - 1.0).abs() < 1e-12);
        // The two branches meet at the threshold to within the standard's rounding of its
        // constants.
        assert!((srgb_to_linear(0.04045 + 1e-12) - srgb_to_linear(0.04045)).abs() < 1e-7);
    }

    #[test]
    fn lms_matrix_reproduces_cie2012_xyz() {
        // 2e-6: data/README.md states M reproduces the CIE 2012 table within 1.9e-6.
        let rows = parse_grid_csv(
            "cie2012_xyz_2deg.csv",
            include_str!("../data/cie2012_xyz_2deg.csv"),
            "wavelength_nm,x,y,z",
        );
        let ss = stockman_sharpe_2deg();
        for (k, row) in rows.iter().enumerate() {
            let xyz = mat_vec(&LMS_TO_XYZ_2012, [ss.l[k], ss.m[k], ss.s[k]]);
            for a in 0..3 {
                assert!((xyz[a] - row[a + 1].unwrap()).abs() < 2e-6, "row {k}");
            }
        }
    }

    #[test]
    fn sampled_observers_match_asano_spreads() {
        // Within 10 % of the JSON SDs: with 2000 samples the SD estimate has a relative standard
        // error of 1/√4000 ≈ 1.6 %, so 10 % is a > 6σ bound (clipping at −100 % affects the macula
        // SD by < 0.1 %).
        let json: serde_json::Value = serde_json::from_str(ASANO_JSON).unwrap();
        let expected = &json["sd_scaled_step2"]["values_exact"];
        let mut rng = StdRng::seed_from_u64(2016);
        let samples: Vec<ObserverParameters> = (0..2000).map(|_| sample_observer_parameters(&mut rng)).collect();
        for s in &samples {
            s.validate().unwrap();
            assert_eq!(s.field_size_deg, 2.0);
            assert!((20.0..=70.0).contains(&s.age_years));
        }
        type Getter = fn(&ObserverParameters) -> f64;
        let fields: [(&str, Getter); 8] = [
            ("od_lens_pct", |p| p.od_lens_pct),
            ("od_macula_pct", |p| p.od_macula_pct),
            ("od_L_pct", |p| p.od_l_pct),
            ("od_M_pct", |p| p.od_m_pct),
            ("od_S_pct", |p| p.od_s_pct),
            ("shift_L_nm", |p| p.shift_l_nm),
            ("shift_M_nm", |p| p.shift_m_nm),
            ("shift_S_nm", |p| p.shift_s_nm),
        ];
        let n = samples.len() as f64;
        for (key, get) in fields {
            let mean = samples.iter().map(get).sum::<f64>() / n;
            let sd = (samples.iter().map(|p| (get(p) - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            let want = expected[key].as_f64().unwrap();
            assert!((sd / want - 1.0).abs() < 0.1, "{key}: sd {sd} vs {want}");
            // Mean 0 within 5 standard errors.
            assert!(mean.abs() < 5.0 * want / n.sqrt(), "{key}: mean {mean}");
        }
        let mean_age = samples.iter().map(|p| p.age_years).sum::<f64>() / n;
        // Uniform 20..=70 has mean 45 and SD 14.4; 5 standard errors ≈ 1.6 years.
        assert!((mean_age - 45.0).abs() < 1.6, "mean age {mean_age}");
    }

    #[test]
    fn validation_errors_name_the_field() {
        // Exact messages: API clients see them verbatim.
        let too_old = ObserverParameters {
            age_years: 120.0,
            ..Default::default()
        };
        assert_eq!(
            too_old.validate().unwrap_err().to_string(),
            "age_years must be within 10..=90, got 120"
        );
        let cases: [(ObserverParameters, &str); 5] = [
            (
                ObserverParameters {
                    field_size_deg: 0.5,
                    ..Default::default()
                },
                "field_size_deg",
            ),
            (
                ObserverParameters {
                    od_macula_pct: -150.0,
                    ..Default::default()
                },
                "od_macula_pct",
            ),
            (
                ObserverParameters {
                    od_s_pct: 301.0,
                    ..Default::default()
                },
                "od_s_pct",
            ),
            (
                ObserverParameters {
                    shift_m_nm: -16.0,
                    ..Default::default()
                },
                "shift_m_nm",
            ),
            (
                ObserverParameters {
                    od_lens_pct: f64::NAN,
                    ..Default::default()
                },
                "od_lens_pct must be finite",
            ),
        ];
        for (params, needle) in cases {
            let msg = params.validate().unwrap_err().to_string();
            assert!(msg.starts_with(needle), "{msg:?} should name {needle}");
        }
        assert!(ObserverParameters::default().validate().is_ok());

        let grid: Vec<f64> = (0..12).map(|i| 400.0 + 10.0 * i as f64).collect();
        let ones = vec![1.0; 12];
        let table = |w: Vec<f64>, l: Vec<f64>, m: Vec<f64>, s: Vec<f64>| SpectralSensitivity::Table {
            wavelengths_nm: w,
            l,
            m,
            s,
        };
        let err = |t: SpectralSensitivity| t.validate().unwrap_err().to_string();
        assert!(table(grid.clone(), ones.clone(), ones.clone(), ones.clone())
            .validate()
            .is_ok());
        assert_eq!(
            err(table(
                grid[..5].to_vec(),
                ones[..5].to_vec(),
                ones[..5].to_vec(),
                ones[..5].to_vec()
            )),
            "wavelengths_nm needs at least 10 samples, got 5"
        );
        assert_eq!(
            err(table(grid.clone(), ones.clone(), ones[..11].to_vec(), ones.clone())),
            "m has 11 samples but wavelengths_nm has 12"
        );
        let mut unsorted = grid.clone();
        unsorted.swap(3, 4);
        assert!(err(table(unsorted, ones.clone(), ones.clone(), ones.clone())).starts_with("wavelengths_nm[4]"));
        let mut wide = grid.clone();
        wide[11] = 900.0;
        assert!(err(table(wide, ones.clone(), ones.clone(), ones.clone()))
            .starts_with("wavelengths_nm[11] must be within 360..=850"));
        let mut negative = ones.clone();
        negative[2] = -0.1;
        assert_eq!(
            err(table(grid.clone(), ones.clone(), ones.clone(), negative)),
            "s[2] must be non-negative, got -0.1"
        );
        let mut nan = ones.clone();
        nan[0] = f64::NAN;
        assert!(err(table(grid.clone(), nan, ones.clone(), ones.clone())).starts_with("l[0] must be finite"));
        assert_eq!(
            err(table(grid.clone(), ones.clone(), vec![0.0; 12], ones.clone())),
            "m must be positive somewhere within 390..=830 nm"
        );

        let gauss = |centre_nm, fwhm_nm| ProjectorSpectrum::Gaussian { centre_nm, fwhm_nm };
        assert!(gauss(900.0, 20.0)
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("centre_nm"));
        assert!(gauss(500.0, 0.5)
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("fwhm_nm"));
        // A 1-nm band at 380 nm lies entirely below the grid.
        assert!(gauss(380.0, 1.0)
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("centre_nm: only"));
        assert!(gauss(380.0, 30.0).validate().is_ok());
        let sampled = ProjectorSpectrum::Sampled {
            wavelengths_nm: (0..10).map(|i| 360.0 + 2.0 * i as f64).collect(),
            power: vec![1.0; 10],
        };
        assert!(sampled.validate().unwrap_err().to_string().starts_with("power: only"));
        let short_power = ProjectorSpectrum::Sampled {
            wavelengths_nm: grid.clone(),
            power: vec![1.0; 3],
        };
        assert_eq!(
            short_power.validate().unwrap_err().to_string(),
            "power has 3 samples but wavelengths_nm has 12"
        );
    }

    #[test]
    fn table_of_the_shipped_table_returns_it() {
        // 2e-5: interpolation at the table's own wavelengths is exact; the only change is
        // renormalising the grid peaks from 0.99998 to 1.
        let ss = stockman_sharpe_2deg();
        let table = SpectralSensitivity::Table {
            wavelengths_nm: wavelengths_nm().collect(),
            l: ss.l.clone(),
            m: ss.m.clone(),
            s: ss.s.clone(),
        };
        table.validate().unwrap();
        let (diff, _) = max_abs_diff(&table.cone_fundamentals(), ss);
        assert!(diff < 2e-5, "max abs diff {diff}");
    }

    #[test]
    fn five_nm_table_interpolates_close_to_the_1nm_table() {
        // 2e-2: linear interpolation over 5 nm errs by up to h²/8·|x̄''|, measured 1.2e-2 where S
        // bends most (457 nm).
        let rows: Vec<[f64; 4]> = include_str!("../data/lms_stockman_sharpe_2000_2deg_5nm.csv")
            .lines()
            .skip(1)
            .filter(|l| !l.is_empty())
            .map(|l| {
                let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
                [v[0], v[1], v[2], v[3]]
            })
            .collect();
        let table = SpectralSensitivity::Table {
            wavelengths_nm: rows.iter().map(|r| r[0]).collect(),
            l: rows.iter().map(|r| r[1]).collect(),
            m: rows.iter().map(|r| r[2]).collect(),
            s: rows.iter().map(|r| r[3]).collect(),
        };
        table.validate().unwrap();
        let (diff, at_nm) = max_abs_diff(&table.cone_fundamentals(), stockman_sharpe_2deg());
        assert!(diff < 2e-2, "max abs diff {diff} at {at_nm} nm");
    }

    #[test]
    fn json_forms_round_trip() {
        // Exact: serde must accept the documented JSON and reject unknown fields.
        let p: SpectralSensitivity =
            serde_json::from_str(r#"{"kind":"parameters","age_years":50,"shift_l_nm":1.5}"#).unwrap();
        assert_eq!(
            p,
            SpectralSensitivity::Parameters(ObserverParameters {
                age_years: 50.0,
                shift_l_nm: 1.5,
                ..Default::default()
            })
        );
        let default: SpectralSensitivity = serde_json::from_str(r#"{"kind":"parameters"}"#).unwrap();
        assert_eq!(default, SpectralSensitivity::default());
        let json = serde_json::to_string(&p).unwrap();
        assert!(json.starts_with(r#"{"kind":"parameters","age_years":50.0"#), "{json}");
        assert_eq!(serde_json::from_str::<SpectralSensitivity>(&json).unwrap(), p);
        assert!(serde_json::from_str::<SpectralSensitivity>(r#"{"kind":"parameters","age":50}"#).is_err());
        assert!(serde_json::from_str::<SpectralSensitivity>(
            r#"{"kind":"table","wavelengths_nm":[400],"l":[1],"m":[1],"s":[1],"x":[1]}"#
        )
        .is_err());
        let t: SpectralSensitivity =
            serde_json::from_str(r#"{"kind":"table","wavelengths_nm":[400],"l":[1],"m":[1],"s":[1]}"#).unwrap();
        assert!(matches!(t, SpectralSensitivity::Table { .. }));

        let g: ProjectorSpectrum = serde_json::from_str(r#"{"kind":"gaussian","centre_nm":450,"fwhm_nm":20}"#).unwrap();
        assert_eq!(g, paper_projectors()[0]);
        assert!(serde_json::from_str::<ProjectorSpectrum>(
            r#"{"kind":"gaussian","centre_nm":450,"fwhm_nm":20,"peak":1}"#
        )
        .is_err());
        let s: ProjectorSpectrum =
            serde_json::from_str(r#"{"kind":"sampled","wavelengths_nm":[400,410],"power":[1,2]}"#).unwrap();
        assert_eq!(
            serde_json::from_str::<ProjectorSpectrum>(&serde_json::to_string(&s).unwrap()).unwrap(),
            s
        );
    }
}
