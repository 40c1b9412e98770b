//! Cone fundamentals and the standard observer's (Stockman & Sharpe 2000, 2°).

use crate::physics::spectral::{parse_lms_table, SS_2DEG_CSV};
use std::sync::OnceLock;

// Cone fundamentals

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
    pub(crate) fn channels(&self) -> [&[f64]; 3] {
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
