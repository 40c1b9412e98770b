//! Individual observers: the CIE 170-1:2006 physiological model with the eight parameters of Asano et al. (2016).

use crate::physics::spectral::{
    asano_scaled_sds, check_range, cie2006_templates, wavelengths_nm, ConeFundamentals, SpectralError, N_WAVELENGTHS,
    WAVELENGTH_START_NM, WAVELENGTH_STEP_NM,
};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// Physiological parameters of one observer: the CIE 170-1:2006 age and field size plus the eight
/// deviations of Asano et al. (2016). The default (age 32, 2° field, all deviations 0) is the CIE
/// 2006 2° standard observer, i.e. the Stockman & Sharpe 2° fundamentals.
///
/// In JSON every field is optional (missing fields take the default) and unknown fields are
/// rejected.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct ObserverParameters {
    /// Age in years; drives the ocular-media (lens) density, CIE 170-1 §5.
    #[cfg_attr(feature = "openapi", schema(minimum = 10.0, maximum = 90.0))]
    pub age_years: f64,
    /// Angular diameter of the viewing field in degrees; drives the photopigment and macular
    /// densities.
    #[cfg_attr(feature = "openapi", schema(minimum = 1.0, maximum = 10.0))]
    pub field_size_deg: f64,
    /// Deviation of the ocular-media density, in % of its age-dependent value: D_ocul · (1 +
    /// v/100).
    #[cfg_attr(feature = "openapi", schema(minimum = -100.0, maximum = 300.0))]
    pub od_lens_pct: f64,
    /// Deviation of the peak macular pigment density, in %: D_mac,max · (1 + v/100).
    #[cfg_attr(feature = "openapi", schema(minimum = -100.0, maximum = 300.0))]
    pub od_macula_pct: f64,
    /// Deviation of the L photopigment peak optical density, in %: D_max,L · (1 + v/100).
    #[cfg_attr(feature = "openapi", schema(minimum = -100.0, maximum = 300.0))]
    pub od_l_pct: f64,
    /// Deviation of the M photopigment peak optical density, in %: D_max,M · (1 + v/100).
    #[cfg_attr(feature = "openapi", schema(minimum = -100.0, maximum = 300.0))]
    pub od_m_pct: f64,
    /// Deviation of the S photopigment peak optical density, in %: D_max,S · (1 + v/100).
    #[cfg_attr(feature = "openapi", schema(minimum = -100.0, maximum = 300.0))]
    pub od_s_pct: f64,
    /// Shift of the L absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    #[cfg_attr(feature = "openapi", schema(minimum = -15.0, maximum = 15.0))]
    pub shift_l_nm: f64,
    /// Shift of the M absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    #[cfg_attr(feature = "openapi", schema(minimum = -15.0, maximum = 15.0))]
    pub shift_m_nm: f64,
    /// Shift of the S absorbance spectrum along the wavelength axis in nm (positive = longer
    /// wavelengths).
    #[cfg_attr(feature = "openapi", schema(minimum = -15.0, maximum = 15.0))]
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
pub(crate) const AGE_RANGE_YEARS: (f64, f64) = (10.0, 90.0);
pub(crate) const FIELD_RANGE_DEG: (f64, f64) = (1.0, 10.0);
pub(crate) const DENSITY_PCT_RANGE: (f64, f64) = (-100.0, 300.0);
pub(crate) const SHIFT_RANGE_NM: (f64, f64) = (-15.0, 15.0);

/// Rounds a field-size-dependent density to 3 decimals (half away from zero), as the CIE TC1-97
/// reference implementation of CIE 170-1:2006 does. The official 2° and 10° tables were computed
/// this way: without the rounding the 10° fundamentals are off by 1.3e-4 instead of 7e-5.
pub(crate) fn round_3_decimals(density: f64) -> f64 {
    (density * 1000.0).round() / 1000.0
}

/// CIE 170-1:2006 peak optical density of the L and M photopigments for a field of `field_deg`
/// degrees.
pub(crate) fn d_max_lm(field_deg: f64) -> f64 {
    round_3_decimals(0.38 + 0.54 * (-field_deg / 1.333).exp())
}

/// CIE 170-1:2006 peak optical density of the S photopigment for a field of `field_deg` degrees.
pub(crate) fn d_max_s(field_deg: f64) -> f64 {
    round_3_decimals(0.30 + 0.45 * (-field_deg / 1.333).exp())
}

/// CIE 170-1:2006 peak macular pigment density for a field of `field_deg` degrees.
pub(crate) fn d_mac_max(field_deg: f64) -> f64 {
    round_3_decimals(0.485 * (-field_deg / 6.132).exp())
}

/// CIE 170-1:2006 age factor of the age-dependent ocular-media density: D_ocul = d_ocul1·factor +
/// d_ocul2.
pub(crate) fn lens_age_factor(age_years: f64) -> f64 {
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
pub(crate) fn template_at(values: &[f64], x_nm: f64, extend_long: bool) -> Option<f64> {
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
pub(crate) fn normalise_peak(values: &mut [f64]) {
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
