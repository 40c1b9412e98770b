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

mod colour;
mod cones;
mod data;
mod error;
mod individual;
mod projectors;
mod sensitivity;
mod tables;

pub use colour::*;
pub use cones::*;
use data::*;
pub use error::*;
pub use individual::*;
pub use projectors::*;
pub use sensitivity::*;
use tables::*;
#[cfg(feature = "openapi")]
pub use tables::{SampleValue, WavelengthSample};

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

#[cfg(test)]
mod tests {
    use super::*;

    use rand::Rng;

    use rand::rngs::StdRng;
    use rand::SeedableRng;

    fn ss_10deg() -> ConeFundamentals {
        parse_lms_table(
            "lms_stockman_sharpe_2000_10deg.csv",
            include_str!(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../data/lms_stockman_sharpe_2000_10deg.csv"
            )),
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
            include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/cie2012_xyz_2deg.csv")),
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
        let rows: Vec<[f64; 4]> = include_str!(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../data/lms_stockman_sharpe_2000_2deg_5nm.csv"
        ))
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
