//! Colour: sRGB ⇄ linear ⇄ XYZ ⇄ LMS.

use std::sync::OnceLock;

// Colour: sRGB ⇄ linear ⇄ XYZ ⇄ LMS

pub(crate) type Mat3 = [[f64; 3]; 3];

/// Linear sRGB → CIE XYZ (D65), IEC 61966-2-1:1999 §5.2.
pub(crate) const SRGB_TO_XYZ: Mat3 = [
    [0.4124, 0.3576, 0.1805],
    [0.2126, 0.7152, 0.0722],
    [0.0193, 0.1192, 0.9505],
];

/// Stockman–Sharpe 2° LMS → CIE 2012 2° XYZ (CIE 170-2:2015): XYZ = M·LMS, reproducing the CIE 2012
/// table to 1.9e-6 (data/README.md §1).
pub(crate) const LMS_TO_XYZ_2012: Mat3 = [
    [1.94735469, -1.41445123, 0.36476327],
    [0.68990272, 0.34832189, 0.0],
    [0.0, 0.0, 1.93485343],
];

pub(crate) fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

pub(crate) fn mat_vec(a: &Mat3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

/// Inverse of a well-conditioned constant 3×3 matrix (adjugate / determinant).
pub(crate) fn mat_inverse(a: &Mat3) -> Mat3 {
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
pub(crate) fn colour_matrices() -> &'static (Mat3, Mat3) {
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
/// use eyekey_core::physics::spectral::{linear_srgb_to_lms, lms_to_linear_srgb};
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
