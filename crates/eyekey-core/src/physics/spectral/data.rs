//! The embedded reference tables (CIE 2006, Stockman & Sharpe, Asano et al. 2016), parsed once.

use crate::physics::spectral::{wavelengths_nm, ConeFundamentals, N_WAVELENGTHS};
use serde::Deserialize;
use std::sync::OnceLock;

// Embedded reference data (parsed once)

pub(crate) const SS_2DEG_CSV: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../data/lms_stockman_sharpe_2000_2deg.csv"
));
pub(crate) const CIE2006_TEMPLATES_CSV: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../data/cie2006_model_templates_1nm.csv"
));
pub(crate) const ASANO_JSON: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../data/asano2016_individual_observer_params.json"
));

/// Parses one of the shipped 1-nm CSV tables: checks the header and that the first column is
/// exactly the spectral grid. Empty cells become `None`. The files are compiled in, so a malformed
/// file is a build defect (caught by the unit tests), not a run-time condition: it panics with the
/// reason.
pub(crate) fn parse_grid_csv(name: &str, text: &str, header: &str) -> Vec<Vec<Option<f64>>> {
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

pub(crate) fn column(name: &str, rows: &[Vec<Option<f64>>], col: usize) -> Vec<f64> {
    rows.iter()
        .map(|r| r[col].unwrap_or_else(|| panic!("{name}: missing value in column {col}")))
        .collect()
}

pub(crate) fn parse_lms_table(name: &str, text: &str) -> ConeFundamentals {
    let rows = parse_grid_csv(name, text, "wavelength_nm,l,m,s");
    ConeFundamentals {
        l: column(name, &rows, 1),
        m: column(name, &rows, 2),
        s: column(name, &rows, 3),
    }
}

/// Building blocks of the CIE 170-1:2006 physiological observer on the 1-nm grid (data/README.md
/// §2).
pub(crate) struct Cie2006Templates {
    /// log10 low-density absorbance A_i(λ) of the L, M, S photopigments, starting at 390 nm. L and
    /// M cover the grid; S stops at 615 nm, beyond which CIE 170-1 leaves it undefined.
    pub(crate) log10_absorbance: [Vec<f64>; 3],
    /// Macular pigment density relative to its peak (scaled by D_mac,max of the field size).
    pub(crate) d_macula_rel: Vec<f64>,
    /// Age-dependent part of the ocular-media density at age 32.
    pub(crate) d_ocul1_32: Vec<f64>,
    /// Age-independent part of the ocular-media density.
    pub(crate) d_ocul2: Vec<f64>,
}

pub(crate) fn cie2006_templates() -> &'static Cie2006Templates {
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
pub(crate) struct AsanoSds {
    pub(crate) od_lens_pct: f64,
    pub(crate) od_macula_pct: f64,
    #[serde(rename = "od_L_pct")]
    pub(crate) od_l_pct: f64,
    #[serde(rename = "od_M_pct")]
    pub(crate) od_m_pct: f64,
    #[serde(rename = "od_S_pct")]
    pub(crate) od_s_pct: f64,
    #[serde(rename = "shift_L_nm")]
    pub(crate) shift_l_nm: f64,
    #[serde(rename = "shift_M_nm")]
    pub(crate) shift_m_nm: f64,
    #[serde(rename = "shift_S_nm")]
    pub(crate) shift_s_nm: f64,
}

/// The "scaled" (step 2) SDs that Asano's model uses for populations: the literature SDs × 0.98
/// (lens, macula) and × 0.5 (the others), taken unrounded from the shipped JSON
/// (`sd_scaled_step2.values_exact`).
pub(crate) fn asano_scaled_sds() -> &'static AsanoSds {
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
