//! Zernike polynomials and wavefront coefficient sets after OSA/ANSI Z80.28 (= ISO 24157).
//!
//! The paper's Eq. 3 writes the wavefront error as W(ρ, θ) = Σ C_n^m Z_n^m(ρ, θ); its Eq. 4 gives the
//! radial sum. Eq. 4 as printed uses m where |m| belongs and has no normalisation, so eyekey uses the
//! standard's form:
//!
//! ```text
//! Z_n^m(ρ, θ) = N_n^m · R_n^|m|(ρ) · cos(mθ)      (m ≥ 0)
//! Z_n^m(ρ, θ) = N_n^m · R_n^|m|(ρ) · sin(|m|θ)    (m < 0)
//! R_n^|m|(ρ)  = Σ_{s=0}^{(n−|m|)/2} (−1)^s (n−s)! / (s! ((n+|m|)/2 − s)! ((n−|m|)/2 − s)!) · ρ^(n−2s)
//! N_n^m       = √(2(n+1) / (1 + δ_m0))
//! ```
//!
//! so every term has unit RMS over the unit disk, and terms are addressed by the single index
//! j = (n(n+2) + m)/2. Coefficients are in µm for a stated pupil diameter in mm; ρ is the distance from the
//! pupil centre divided by the pupil radius, x horizontal, y vertical, θ counter-clockwise from +x.
//!
//! Everything is evaluated in Cartesian form, ρ^|m| cos(|m|θ) = Re (x+iy)^|m| and
//! ρ^|m| sin(|m|θ) = Im (x+iy)^|m|, which is smooth at the pupil centre and needs no `atan2`.
//! [`ZernikePolynomial`] expands a whole set into monomials once for the hot loops of light transport.

use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

/// Highest radial order supported by the coefficient sets and by [`ZernikePolynomial`] (66 terms).
pub const MAX_RADIAL_ORDER: u32 = 10;

/// Largest accepted pupil diameter in mm (a fully dilated human pupil is about 8–9 mm).
pub const MAX_PUPIL_DIAMETER_MM: f64 = 12.0;

/// Largest accepted magnitude of a single coefficient in µm; larger values are not a human eye.
pub const MAX_COEFFICIENT_UM: f64 = 50.0;

/// Largest accepted magnitude of a prescription's sphere in dioptres.
pub const MAX_SPHERE_D: f64 = 20.0;

/// Largest accepted magnitude of a prescription's cylinder in dioptres.
pub const MAX_CYLINDER_D: f64 = 10.0;

/// Highest monomial degree held by [`ZernikePolynomial`]: the radial order bounds the degree.
const MAX_DEGREE: usize = MAX_RADIAL_ORDER as usize;

/// Monomials x^a y^b with a + b ≤ MAX_DEGREE.
const N_MONOMIALS: usize = (MAX_DEGREE + 1) * (MAX_DEGREE + 2) / 2;

/// Monomials of the first derivatives, a + b ≤ MAX_DEGREE − 1.
const N_GRADIENT_MONOMIALS: usize = MAX_DEGREE * (MAX_DEGREE + 1) / 2;

/// Terms in a fresh coefficient set: orders 0..=6, the range Z80.28 tabulates and eyekey measures.
const DEFAULT_TERMS: usize = n_terms_for_order(6);

/// Single OSA index j = (n(n+2) + m)/2 of the term Z_n^m (Z80.28 §4.4).
///
/// # Panics
///
/// Panics unless |m| ≤ n and n − |m| is even, i.e. unless Z_n^m exists.
pub fn osa_index(n: u32, m: i32) -> usize {
    let m_abs = m.unsigned_abs();
    assert!(
        m_abs <= n && (n - m_abs) % 2 == 0,
        "Z_n^m needs |m| <= n and n - |m| even, got n = {n}, m = {m}"
    );
    let (n, m) = (i64::from(n), i64::from(m));
    ((n * (n + 2) + m) / 2) as usize
}

/// Radial order n and azimuthal frequency m of the term with OSA index j (inverse of [`osa_index`]).
pub fn osa_nm(j: usize) -> (u32, i32) {
    // Order n holds j in [n(n+1)/2, (n+1)(n+2)/2); start from the float root, then correct rounding.
    let mut n = ((((8 * j + 1) as f64).sqrt() - 1.0) / 2.0) as usize;
    while n * (n + 1) / 2 > j {
        n -= 1;
    }
    while (n + 1) * (n + 2) / 2 <= j {
        n += 1;
    }
    let m = 2 * j as i64 - (n * (n + 2)) as i64;
    (n as u32, m as i32)
}

/// Number of terms in a complete set up to and including radial order n: (n+1)(n+2)/2.
pub const fn n_terms_for_order(n: u32) -> usize {
    let n = n as usize;
    (n + 1) * (n + 2) / 2
}

/// Value of the OSA-normalised term Z_j at unit-disk Cartesian coordinates (x, y) (Eq. 4, Z80.28 §4.3).
///
/// Terms with m < 0 are the sine terms. Each term has unit RMS over the unit disk. Points outside the
/// disk are evaluated as the polynomial continues; they have no optical meaning.
pub fn zernike_value(j: usize, x: f64, y: f64) -> f64 {
    let (n, m) = osa_nm(j);
    let m_abs = m.unsigned_abs();
    let (p, _) = radial_even_part(n, m_abs, x * x + y * y);
    let (re, im) = complex_pow(x, y, m_abs);
    normalisation(n, m) * p * if m >= 0 { re } else { im }
}

/// Analytic gradient [∂Z_j/∂x, ∂Z_j/∂y] in unit-disk coordinates.
///
/// With R_n^|m|(ρ) = ρ^|m| P(ρ²) and (x+iy)^|m| = A + iB, Z_j = N·P(x²+y²)·A (or ·B), and
/// ∂(x+iy)^k/∂x = k(x+iy)^(k−1), ∂(x+iy)^k/∂y = i·k(x+iy)^(k−1), so no finite differences are needed.
pub fn zernike_gradient(j: usize, x: f64, y: f64) -> [f64; 2] {
    let (n, m) = osa_nm(j);
    let k = m.unsigned_abs();
    let (p, dp) = radial_even_part(n, k, x * x + y * y);
    let (a, b) = complex_pow(x, y, k);
    // k·(x+iy)^(k−1) = c + i·d
    let (c, d) = if k == 0 {
        (0.0, 0.0)
    } else {
        let (c, d) = complex_pow(x, y, k - 1);
        (f64::from(k) * c, f64::from(k) * d)
    };
    let [gx, gy] = if m >= 0 {
        // ∂A/∂x = c, ∂A/∂y = −d
        [2.0 * x * dp * a + p * c, 2.0 * y * dp * a - p * d]
    } else {
        // ∂B/∂x = d, ∂B/∂y = c
        [2.0 * x * dp * b + p * d, 2.0 * y * dp * b + p * c]
    };
    let norm = normalisation(n, m);
    [norm * gx, norm * gy]
}

/// N_n^m = √(2(n+1)/(1+δ_m0)), the unit-RMS normalisation of Z80.28.
fn normalisation(n: u32, m: i32) -> f64 {
    let numerator = if m == 0 { 1.0 } else { 2.0 } * (f64::from(n) + 1.0);
    numerator.sqrt()
}

/// k! in f64; exact up to 22!, far beyond the orders eyekey uses.
fn factorial(k: u32) -> f64 {
    (1..=k).fold(1.0, |acc, i| acc * f64::from(i))
}

/// Binomial coefficient C(n, k) in f64 (exact for the small arguments used here).
fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// Coefficient of ρ^(n−2s) in R_n^|m|(ρ): the bracket of Eq. 4, with |m| in the factorials.
fn radial_coefficient(n: u32, m_abs: u32, s: u32) -> f64 {
    let half_sum = (n + m_abs) / 2;
    let half_diff = (n - m_abs) / 2;
    let magnitude = factorial(n - s) / (factorial(s) * factorial(half_sum - s) * factorial(half_diff - s));
    if s % 2 == 0 {
        magnitude
    } else {
        -magnitude
    }
}

/// P(t) and P'(t), where R_n^|m|(ρ) = ρ^|m| P(ρ²); Horner in t = ρ², highest power first.
fn radial_even_part(n: u32, m_abs: u32, t: f64) -> (f64, f64) {
    let half_diff = (n - m_abs) / 2;
    let (mut p, mut dp) = (0.0, 0.0);
    // The coefficient of t^k is the s = half_diff − k term of Eq. 4.
    for s in 0..=half_diff {
        dp = dp * t + p;
        p = p * t + radial_coefficient(n, m_abs, s);
    }
    (p, dp)
}

/// R_n^k(ρ), the unnormalised radial polynomial; zero when k > n.
fn radial(n: u32, k: u32, rho: f64) -> f64 {
    if k > n {
        return 0.0;
    }
    let (p, _) = radial_even_part(n, k, rho * rho);
    p * rho.powi(k as i32)
}

/// (x + iy)^k as (real, imaginary).
fn complex_pow(x: f64, y: f64, k: u32) -> (f64, f64) {
    let (mut re, mut im) = (1.0, 0.0);
    for _ in 0..k {
        (re, im) = (re * x - im * y, re * y + im * x);
    }
    (re, im)
}

/// Index of the monomial x^a y^b: grouped by total degree t = a + b, then by a, so the monomials of
/// degree ≤ d are exactly the first (d+1)(d+2)/2 entries whatever the maximum degree.
const fn monomial_index(a: usize, b: usize) -> usize {
    let t = a + b;
    t * (t + 1) / 2 + a
}

/// Fills `table[monomial_index(a, b)] = x^a y^b` for a + b ≤ d, one multiplication per entry, and
/// returns how many entries that is. Degree t's row comes from row t − 1: times y for a < t, and
/// x^(t−1)·x for a = t.
#[inline(always)]
fn monomial_table<const N: usize>(x: f64, y: f64, d: usize, table: &mut [f64; N]) -> usize {
    table[0] = 1.0;
    let mut previous = 0;
    for t in 1..=d {
        let row = previous + t;
        for a in 0..t {
            table[row + a] = table[previous + a] * y;
        }
        table[row + t] = table[previous + t - 1] * x;
        previous = row;
    }
    previous + d + 1
}

/// A sum of Zernike terms in Cartesian monomial form, for fast evaluation in hot loops.
///
/// The coefficients of W, ∂W/∂x and ∂W/∂y as polynomials in the unit-disk coordinates x, y are computed
/// once; each evaluation then builds a table of monomials on the stack and takes a dot product. The
/// degree is that of the highest term with a non-zero coefficient, so low-order sets stay cheap.
///
/// Expanding to monomials loses a little precision through cancellation at high order (below 1e-11
/// at order 10 on the unit disk), far below any optical significance.
#[derive(Clone, Debug, PartialEq)]
pub struct ZernikePolynomial {
    degree: usize,
    /// Coefficient of x^a y^b at `monomial_index(a, b)`.
    value: [f64; N_MONOMIALS],
    /// [∂/∂x, ∂/∂y] coefficients of x^a y^b at `monomial_index(a, b)`, degree ≤ `degree − 1`.
    gradient: [[f64; 2]; N_GRADIENT_MONOMIALS],
}

impl ZernikePolynomial {
    /// The polynomial Σ_j c_j Z_j on the unit disk, with `coefficients[j]` the coefficient of OSA term j
    /// (Eq. 3).
    ///
    /// # Panics
    ///
    /// Panics if a non-zero coefficient lies beyond radial order [`MAX_RADIAL_ORDER`], i.e. at an index
    /// ≥ `n_terms_for_order(MAX_RADIAL_ORDER)`; validated [`ZernikeCoefficients`] never do.
    pub fn from_coefficients(coefficients: &[f64]) -> Self {
        let mut value = [0.0; N_MONOMIALS];
        let mut degree = 0;
        for (j, &c) in coefficients.iter().enumerate() {
            if c == 0.0 {
                continue;
            }
            assert!(
                j < n_terms_for_order(MAX_RADIAL_ORDER),
                "Zernike term j = {j} is beyond radial order {MAX_RADIAL_ORDER}"
            );
            let (n, m) = osa_nm(j);
            degree = degree.max(n as usize);
            add_term_monomials(&mut value, n, m, c);
        }
        Self::from_monomials(degree, value)
    }

    /// The polynomial of the single term Z_j.
    ///
    /// # Panics
    ///
    /// Panics if j ≥ `n_terms_for_order(MAX_RADIAL_ORDER)`.
    pub fn single_term(j: usize) -> Self {
        assert!(
            j < n_terms_for_order(MAX_RADIAL_ORDER),
            "Zernike term j = {j} is beyond radial order {MAX_RADIAL_ORDER}"
        );
        let (n, m) = osa_nm(j);
        let mut value = [0.0; N_MONOMIALS];
        add_term_monomials(&mut value, n, m, 1.0);
        Self::from_monomials(n as usize, value)
    }

    /// Differentiates the monomials once so that [`Self::gradient`] is a plain dot product.
    fn from_monomials(degree: usize, value: [f64; N_MONOMIALS]) -> Self {
        let mut gradient = [[0.0; 2]; N_GRADIENT_MONOMIALS];
        for t in 0..degree {
            for a in 0..=t {
                let b = t - a;
                gradient[monomial_index(a, b)] = [
                    (a + 1) as f64 * value[monomial_index(a + 1, b)],
                    (b + 1) as f64 * value[monomial_index(a, b + 1)],
                ];
            }
        }
        Self {
            degree,
            value,
            gradient,
        }
    }

    /// W(x, y) at unit-disk coordinates.
    #[inline]
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let mut monomials = [0.0; N_MONOMIALS];
        let len = monomial_table(x, y, self.degree.min(MAX_DEGREE), &mut monomials);
        monomials[..len]
            .iter()
            .zip(&self.value[..len])
            .map(|(m, c)| m * c)
            .sum()
    }

    /// [∂W/∂x, ∂W/∂y] at unit-disk coordinates; allocation-free, for the transport hot loop.
    #[inline]
    pub fn gradient(&self, x: f64, y: f64) -> [f64; 2] {
        if self.degree == 0 {
            return [0.0; 2];
        }
        // The monomials of degree t, x^a y^(t−a) at [a], made from degree t − 1's in place as
        // `monomial_table` makes them, and added as they are made: the same products and sums in the same
        // order as a dot product with the whole table, without filling it.
        let mut row = [0.0; MAX_DEGREE];
        row[0] = 1.0;
        let (mut gx, mut gy) = (0.0, 0.0);
        for t in 0..=(self.degree - 1).min(MAX_DEGREE - 1) {
            if t > 0 {
                row[t] = row[t - 1] * x;
                for m in &mut row[..t] {
                    *m *= y;
                }
            }
            let first = monomial_index(0, t);
            for (m, &[cx, cy]) in row[..=t].iter().zip(&self.gradient[first..=first + t]) {
                gx += cx * m;
                gy += cy * m;
            }
        }
        [gx, gy]
    }

    /// [`Self::gradient`] at `GRADIENT_BATCH` points at once (`x[b]`, `y[b]`) into `out[b]`: the same products
    /// and sums in the same order for each point, bit for bit, laid out so that the compiler runs the points side
    /// by side in vector registers. A caller with fewer points fills the rest with any value and ignores theirs.
    #[inline]
    pub fn gradients(
        &self,
        x: &[f64; GRADIENT_BATCH],
        y: &[f64; GRADIENT_BATCH],
        out: &mut [[f64; 2]; GRADIENT_BATCH],
    ) {
        if self.degree == 0 {
            *out = [[0.0; 2]; GRADIENT_BATCH];
            return;
        }
        let mut row = [[0.0; GRADIENT_BATCH]; MAX_DEGREE];
        row[0] = [1.0; GRADIENT_BATCH];
        let (mut gx, mut gy) = ([0.0; GRADIENT_BATCH], [0.0; GRADIENT_BATCH]);
        for t in 0..=(self.degree - 1).min(MAX_DEGREE - 1) {
            if t > 0 {
                let below = row[t - 1];
                for b in 0..GRADIENT_BATCH {
                    row[t][b] = below[b] * x[b];
                }
                for m in &mut row[..t] {
                    for b in 0..GRADIENT_BATCH {
                        m[b] *= y[b];
                    }
                }
            }
            let first = monomial_index(0, t);
            for (m, &[cx, cy]) in row[..=t].iter().zip(&self.gradient[first..=first + t]) {
                for b in 0..GRADIENT_BATCH {
                    gx[b] += cx * m[b];
                    gy[b] += cy * m[b];
                }
            }
        }
        for b in 0..GRADIENT_BATCH {
            out[b] = [gx[b], gy[b]];
        }
    }
}

/// The points [`ZernikePolynomial::gradients`] takes at once.
pub const GRADIENT_BATCH: usize = 8;

/// Adds c·Z_n^m to a monomial coefficient table.
///
/// c·N·Σ_s r_s (x²+y²)^k · {Re, Im}(x+iy)^|m| with k = (n−|m|)/2 − s, expanding
/// (x²+y²)^k = Σ_i C(k,i) x^(2i) y^(2k−2i) and (x+iy)^|m| = Σ_l C(|m|,l) x^(|m|−l) (iy)^l.
fn add_term_monomials(value: &mut [f64; N_MONOMIALS], n: u32, m: i32, c: f64) {
    let m_abs = m.unsigned_abs();
    let k_ang = m_abs as usize;
    let half_diff = (n - m_abs) / 2;
    let scale = c * normalisation(n, m);
    for s in 0..=half_diff {
        let k = (half_diff - s) as usize;
        let radial_coef = scale * radial_coefficient(n, m_abs, s);
        for i in 0..=k {
            let even_coef = radial_coef * binomial(k, i);
            for l in 0..=k_ang {
                // i^l: the cosine term takes the real part (l even), the sine term the imaginary part.
                let sign = match (m >= 0, l % 4) {
                    (true, 0) | (false, 1) => 1.0,
                    (true, 2) | (false, 3) => -1.0,
                    _ => continue,
                };
                value[monomial_index(2 * i + k_ang - l, 2 * (k - i) + l)] += sign * even_coef * binomial(k_ang, l);
            }
        }
    }
}

/// Why a Zernike coefficient set or a prescription was rejected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ZernikeError {
    /// A coefficient is NaN or infinite.
    #[error("coefficients_um[{index}] is not finite")]
    NonFiniteCoefficient {
        /// OSA index j of the offending coefficient.
        index: usize,
    },
    /// A coefficient is larger than any human eye's.
    #[error("coefficients_um[{index}] = {value_um} µm exceeds the plausible magnitude of {max_um} µm")]
    CoefficientOutOfRange {
        /// OSA index j of the offending coefficient.
        index: usize,
        /// The coefficient in µm.
        value_um: f64,
        /// The accepted magnitude in µm.
        max_um: f64,
    },
    /// The pupil diameter is not finite or not in (0, max] mm.
    #[error("pupil_diameter_mm = {value_mm} must be finite and in (0, {max_mm}] mm")]
    PupilOutOfRange {
        /// The pupil diameter in mm.
        value_mm: f64,
        /// The largest accepted diameter in mm.
        max_mm: f64,
    },
    /// More coefficients than radial order [`MAX_RADIAL_ORDER`] holds.
    #[error("coefficients_um has {got} terms; at most {max} are supported")]
    TooManyTerms {
        /// Number of coefficients given.
        got: usize,
        /// Largest accepted number of coefficients.
        max: usize,
    },
    /// Rescaling was asked to extrapolate the wavefront beyond the measured pupil.
    #[error(
        "cannot rescale Zernike coefficients from a {from_mm} mm pupil to a larger {to_mm} mm pupil: \
         the wavefront outside the measured pupil is unknown"
    )]
    CannotEnlargePupil {
        /// Pupil diameter of the measured set in mm.
        from_mm: f64,
        /// Requested, larger, pupil diameter in mm.
        to_mm: f64,
    },
    /// A prescription field is NaN or infinite.
    #[error("{field} is not finite")]
    NonFinite {
        /// Name of the field.
        field: &'static str,
    },
    /// A prescription field lies outside its accepted range.
    #[error("{field} = {value} is outside [{min}, {max}]")]
    PrescriptionOutOfRange {
        /// Name of the field (its unit is in the name).
        field: &'static str,
        /// The value given.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
}

/// Checks a pupil diameter: finite and in (0, [`MAX_PUPIL_DIAMETER_MM`]].
fn check_pupil(value_mm: f64) -> Result<(), ZernikeError> {
    if value_mm.is_finite() && value_mm > 0.0 && value_mm <= MAX_PUPIL_DIAMETER_MM {
        Ok(())
    } else {
        Err(ZernikeError::PupilOutOfRange {
            value_mm,
            max_mm: MAX_PUPIL_DIAMETER_MM,
        })
    }
}

/// A measured wavefront: OSA Zernike coefficients in µm (index = OSA j) for a pupil of stated diameter.
///
/// Deserialisation validates, so a set read from a file always satisfies [`ZernikeCoefficients::validate`].
///
/// ```
/// use eyekey_core::physics::zernike::{Prescription, ZernikeCoefficients};
///
/// // A −2.00 D myope measured over a 6 mm pupil: C(2,0) = −M·r²/(4√3) ≈ +2.598 µm.
/// let rx = Prescription { sphere_d: -2.0, cylinder_d: 0.0, axis_deg: 0.0 };
/// let w = ZernikeCoefficients::from_prescription(&rx, 6.0);
/// assert!((w.get(4) - 2.598).abs() < 1e-3);
/// // Over a 4 mm pupil the same eye shows less defocus in µm but the same power in dioptres.
/// let small = w.rescaled(4.0)?;
/// assert!((small.prescription().sphere_d + 2.0).abs() < 1e-12);
/// # Ok::<(), eyekey_core::physics::zernike::ZernikeError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "UncheckedZernikeCoefficients")]
pub struct ZernikeCoefficients {
    /// Diameter of the pupil the coefficients refer to, in mm.
    pub pupil_diameter_mm: f64,
    /// Coefficient of Z_j in µm at index j (OSA single index); missing trailing terms are zero.
    pub coefficients_um: Vec<f64>,
}

/// The serialised form, validated on the way in.
#[derive(Deserialize)]
struct UncheckedZernikeCoefficients {
    pupil_diameter_mm: f64,
    coefficients_um: Vec<f64>,
}

impl TryFrom<UncheckedZernikeCoefficients> for ZernikeCoefficients {
    type Error = ZernikeError;

    fn try_from(raw: UncheckedZernikeCoefficients) -> Result<Self, Self::Error> {
        Self::new(raw.pupil_diameter_mm, raw.coefficients_um)
    }
}

impl ZernikeCoefficients {
    /// A validated coefficient set; see [`Self::validate`] for the rules.
    pub fn new(pupil_diameter_mm: f64, coefficients_um: Vec<f64>) -> Result<Self, ZernikeError> {
        let set = Self {
            pupil_diameter_mm,
            coefficients_um,
        };
        set.validate()?;
        Ok(set)
    }

    /// A perfect eye: 28 zero coefficients (orders 0..=6) for the given pupil.
    ///
    /// The pupil is not checked here; call [`Self::validate`] if it comes from outside.
    pub fn zero(pupil_diameter_mm: f64) -> Self {
        Self {
            pupil_diameter_mm,
            coefficients_um: vec![0.0; DEFAULT_TERMS],
        }
    }

    /// Checks that the pupil is finite and in (0, 12] mm, that there are at most
    /// `n_terms_for_order(MAX_RADIAL_ORDER)` coefficients, and that each is finite with |c| ≤ 50 µm.
    pub fn validate(&self) -> Result<(), ZernikeError> {
        check_pupil(self.pupil_diameter_mm)?;
        let max = n_terms_for_order(MAX_RADIAL_ORDER);
        if self.coefficients_um.len() > max {
            return Err(ZernikeError::TooManyTerms {
                got: self.coefficients_um.len(),
                max,
            });
        }
        for (index, &c) in self.coefficients_um.iter().enumerate() {
            if !c.is_finite() {
                return Err(ZernikeError::NonFiniteCoefficient { index });
            }
            if c.abs() > MAX_COEFFICIENT_UM {
                return Err(ZernikeError::CoefficientOutOfRange {
                    index,
                    value_um: c,
                    max_um: MAX_COEFFICIENT_UM,
                });
            }
        }
        Ok(())
    }

    /// Coefficient of Z_j in µm, 0 when the set does not hold term j.
    pub fn get(&self, j: usize) -> f64 {
        self.coefficients_um.get(j).copied().unwrap_or(0.0)
    }

    /// Pupil radius r_p in mm.
    pub fn pupil_radius_mm(&self) -> f64 {
        self.pupil_diameter_mm / 2.0
    }

    /// Iterator over the non-zero terms as (j, coefficient in µm).
    fn nonzero_terms(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.coefficients_um
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, c)| c != 0.0)
    }

    /// Wavefront error W in µm at physical pupil coordinates in mm, origin at the pupil centre (Eq. 3).
    ///
    /// Outside the pupil the polynomial is merely continued. For millions of points use
    /// [`Self::polynomial`] instead.
    pub fn wavefront_um(&self, x_mm: f64, y_mm: f64) -> f64 {
        let r = self.pupil_radius_mm();
        let (x, y) = (x_mm / r, y_mm / r);
        self.nonzero_terms().map(|(j, c)| c * zernike_value(j, x, y)).sum()
    }

    /// Wavefront slope [∂W/∂x, ∂W/∂y] with respect to physical pupil coordinates, (1/r_p)·∂W/∂ρ, in
    /// µm per mm = mrad (docs/design.md §2 "Viewer optics"). For millions of points use [`Self::polynomial`].
    pub fn gradient_mrad(&self, x_mm: f64, y_mm: f64) -> [f64; 2] {
        let r = self.pupil_radius_mm();
        let (x, y) = (x_mm / r, y_mm / r);
        let [gx, gy] = self.nonzero_terms().fold([0.0, 0.0], |[gx, gy], (j, c)| {
            let [zx, zy] = zernike_gradient(j, x, y);
            [gx + c * zx, gy + c * zy]
        });
        [gx / r, gy / r]
    }

    /// The set as a unit-disk polynomial in µm (divide its gradient by r_p for mrad).
    ///
    /// # Panics
    ///
    /// Panics on a set with non-zero terms beyond [`MAX_RADIAL_ORDER`], which [`Self::validate`] rejects.
    pub fn polynomial(&self) -> ZernikePolynomial {
        ZernikePolynomial::from_coefficients(&self.coefficients_um)
    }

    /// The same wavefront described over a smaller (or equal) concentric pupil (ISO 24157 Annex B).
    ///
    /// With s = r_new/r_old, W_new(ρ) = W_old(sρ) is again a polynomial of the same order and is
    /// expanded exactly in closed form (Janssen & Dirksen 2006; Lundström & Unsbo 2007, JOSA A 24:569):
    /// the azimuthal frequency m is unchanged and, with R the unnormalised radial polynomials of Eq. 4,
    ///
    /// C'_n^m = Σ_{n' ≥ n, n' ≡ n mod 2} √((n'+1)/(n+1)) · (R_{n'}^n(s) − R_{n'}^{n+2}(s)) · C_{n'}^m.
    ///
    /// For defocus and spherical aberration this gives C'_2^0 = s²C_2^0 − √15 s²(1−s²) C_4^0 and
    /// C'_4^0 = s⁴C_4^0. Enlarging the pupil would extrapolate the wavefront and is an error.
    pub fn rescaled(&self, new_pupil_diameter_mm: f64) -> Result<Self, ZernikeError> {
        self.validate()?;
        check_pupil(new_pupil_diameter_mm)?;
        if new_pupil_diameter_mm > self.pupil_diameter_mm {
            return Err(ZernikeError::CannotEnlargePupil {
                from_mm: self.pupil_diameter_mm,
                to_mm: new_pupil_diameter_mm,
            });
        }
        let s = new_pupil_diameter_mm / self.pupil_diameter_mm;
        // Lower orders of the same m have lower OSA indices, so the set keeps its length.
        let mut rescaled = vec![0.0; self.coefficients_um.len()];
        for (j, c) in self.nonzero_terms() {
            let (n_old, m) = osa_nm(j);
            for n in (m.unsigned_abs()..=n_old).step_by(2) {
                let weight = ((f64::from(n_old) + 1.0) / (f64::from(n) + 1.0)).sqrt()
                    * (radial(n_old, n, s) - radial(n_old, n + 2, s));
                rescaled[osa_index(n, m)] += weight * c;
            }
        }
        Self::new(new_pupil_diameter_mm, rescaled)
    }

    /// RMS wavefront error in µm of the terms whose radial order lies in `orders`.
    ///
    /// With unit-RMS terms (Z80.28) this is the root of the sum of squared coefficients; for the
    /// conventional "higher-order RMS" pass `3..=MAX_RADIAL_ORDER`, for the total without piston and
    /// tilt `2..=MAX_RADIAL_ORDER`.
    pub fn rms_um(&self, orders: RangeInclusive<u32>) -> f64 {
        self.nonzero_terms()
            .filter(|&(j, _)| orders.contains(&osa_nm(j).0))
            .map(|(_, c)| c * c)
            .sum::<f64>()
            .sqrt()
    }

    /// Defocus and astigmatism of a spectacle prescription over the given pupil, the other 25 terms zero.
    ///
    /// With r the pupil radius in mm and the power vector (M, J0, J45) of Thibos et al. (1997):
    /// C(2,0) = −M r²/(4√3), C(2,2) = −J0 r²/(2√6), C(2,−2) = −J45 r²/(2√6) (Thibos, Hong, Bradley &
    /// Applegate 2004, J Vision 4:329). Neither the prescription nor the pupil is checked here.
    pub fn from_prescription(p: &Prescription, pupil_diameter_mm: f64) -> Self {
        let pv = p.power_vector();
        let r2 = (pupil_diameter_mm / 2.0).powi(2);
        let mut set = Self::zero(pupil_diameter_mm);
        set.coefficients_um[osa_index(2, -2)] = -pv.j45_d * r2 / (2.0 * 6f64.sqrt());
        set.coefficients_um[osa_index(2, 0)] = -pv.m_d * r2 / (4.0 * 3f64.sqrt());
        set.coefficients_um[osa_index(2, 2)] = -pv.j0_d * r2 / (2.0 * 6f64.sqrt());
        set
    }

    /// The minus-cylinder prescription equivalent to C(2,0) and C(2,±2); other terms are ignored.
    ///
    /// M = −4√3 C(2,0)/r², J0 = −2√6 C(2,2)/r², J45 = −2√6 C(2,−2)/r² (dioptres, r in mm, C in µm).
    pub fn prescription(&self) -> Prescription {
        let r2 = self.pupil_radius_mm().powi(2);
        let pv = PowerVector {
            m_d: -4.0 * 3f64.sqrt() * self.get(osa_index(2, 0)) / r2,
            j0_d: -2.0 * 6f64.sqrt() * self.get(osa_index(2, 2)) / r2,
            j45_d: -2.0 * 6f64.sqrt() * self.get(osa_index(2, -2)) / r2,
        };
        Prescription::from_power_vector(&pv)
    }

    /// A copy with the terms of the given radial orders set to zero, e.g. `0..=1` for piston and tilt.
    pub fn with_order_range_zeroed(&self, orders: RangeInclusive<u32>) -> Self {
        let mut set = self.clone();
        for (j, c) in set.coefficients_um.iter_mut().enumerate() {
            if orders.contains(&osa_nm(j).0) {
                *c = 0.0;
            }
        }
        set
    }
}

/// A spectacle prescription: sphere and cylinder in dioptres, cylinder axis in degrees.
///
/// Minus- and plus-cylinder forms are both accepted; axis in [0, 180], 180 meaning 0.
/// Deserialisation validates (see [`Prescription::validate`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(try_from = "UncheckedPrescription")]
pub struct Prescription {
    /// Sphere in dioptres (negative for myopia), ±20.
    #[cfg_attr(feature = "openapi", schema(minimum = -20.0, maximum = 20.0))]
    pub sphere_d: f64,
    /// Cylinder in dioptres, either sign, ±10.
    #[cfg_attr(feature = "openapi", schema(minimum = -10.0, maximum = 10.0))]
    pub cylinder_d: f64,
    /// Cylinder axis in degrees, 0..=180.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 180.0))]
    pub axis_deg: f64,
}

/// The serialised form, validated on the way in.
#[derive(Deserialize)]
struct UncheckedPrescription {
    sphere_d: f64,
    cylinder_d: f64,
    axis_deg: f64,
}

impl TryFrom<UncheckedPrescription> for Prescription {
    type Error = ZernikeError;

    fn try_from(raw: UncheckedPrescription) -> Result<Self, Self::Error> {
        let p = Self {
            sphere_d: raw.sphere_d,
            cylinder_d: raw.cylinder_d,
            axis_deg: raw.axis_deg,
        };
        p.validate()?;
        Ok(p)
    }
}

/// Checks one prescription field: finite and within [min, max].
fn check_field(field: &'static str, value: f64, min: f64, max: f64) -> Result<(), ZernikeError> {
    if !value.is_finite() {
        Err(ZernikeError::NonFinite { field })
    } else if value < min || value > max {
        Err(ZernikeError::PrescriptionOutOfRange { field, value, min, max })
    } else {
        Ok(())
    }
}

impl Prescription {
    /// Power vector of Thibos, Wheeler & Horner (1997): M = S + C/2, J0 = −(C/2)cos2θ, J45 = −(C/2)sin2θ.
    pub fn power_vector(&self) -> PowerVector {
        let half_cyl = self.cylinder_d / 2.0;
        let two_theta = 2.0 * self.axis_deg.to_radians();
        PowerVector {
            m_d: self.sphere_d + half_cyl,
            j0_d: -half_cyl * two_theta.cos(),
            j45_d: -half_cyl * two_theta.sin(),
        }
    }

    /// The minus-cylinder prescription of a power vector, axis in [0, 180) (0 when there is no cylinder).
    pub fn from_power_vector(pv: &PowerVector) -> Self {
        let j = pv.j0_d.hypot(pv.j45_d);
        if j == 0.0 {
            return Self {
                sphere_d: pv.m_d,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            };
        }
        // C = −2|J|, so J0 = |J|cos2θ and J45 = |J|sin2θ.
        let mut axis_deg = 0.5 * pv.j45_d.atan2(pv.j0_d).to_degrees();
        if axis_deg < 0.0 {
            axis_deg += 180.0;
        }
        if axis_deg >= 180.0 {
            // −tiny + 180 rounds to 180.
            axis_deg -= 180.0;
        }
        Self {
            sphere_d: pv.m_d + j,
            cylinder_d: -2.0 * j,
            axis_deg,
        }
    }

    /// Checks that every field is finite, |sphere| ≤ 20 D, |cylinder| ≤ 10 D and the axis is in [0, 180].
    pub fn validate(&self) -> Result<(), ZernikeError> {
        check_field("sphere_d", self.sphere_d, -MAX_SPHERE_D, MAX_SPHERE_D)?;
        check_field("cylinder_d", self.cylinder_d, -MAX_CYLINDER_D, MAX_CYLINDER_D)?;
        check_field("axis_deg", self.axis_deg, 0.0, 180.0)
    }
}

/// Power vector (M, J0, J45) in dioptres (Thibos et al. 1997): spherical equivalent and the two
/// Jackson cross-cylinder components.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PowerVector {
    /// Spherical equivalent M in dioptres.
    pub m_d: f64,
    /// Cross-cylinder at axis 0°/90°, in dioptres.
    pub j0_d: f64,
    /// Cross-cylinder at axis 45°/135°, in dioptres.
    pub j45_d: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    /// Gauss–Legendre nodes and weights on [−1, 1] (Newton on the three-term recurrence).
    fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut dp = 0.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0, x);
                    for k in 2..=n {
                        let k = k as f64;
                        (p0, p1) = (p1, ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k);
                    }
                    dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    let dx = p1 / dp;
                    x -= dx;
                    if dx.abs() < 1e-16 {
                        break;
                    }
                }
                (x, 2.0 / ((1.0 - x * x) * dp * dp))
            })
            .collect()
    }

    /// Points (x, y, weight) on the unit disk, weights summing to π: Gauss–Legendre in ρ (with the ρ of
    /// the area element) times uniform θ. Exact for polynomials of degree < min(2·n_rho − 1, n_theta).
    fn disk_quadrature(n_rho: usize, n_theta: usize) -> Vec<(f64, f64, f64)> {
        let mut points = Vec::with_capacity(n_rho * n_theta);
        for (u, w) in gauss_legendre(n_rho) {
            let rho = 0.5 * (u + 1.0);
            for k in 0..n_theta {
                let theta = 2.0 * PI * k as f64 / n_theta as f64;
                let weight = 0.5 * w * rho * 2.0 * PI / n_theta as f64;
                points.push((rho * theta.cos(), rho * theta.sin(), weight));
            }
        }
        points
    }

    fn random_in_disk(rng: &mut ChaCha8Rng, radius: f64) -> (f64, f64) {
        loop {
            let (x, y) = (rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            if x * x + y * y <= 1.0 {
                return (radius * x, radius * y);
            }
        }
    }

    fn random_set(rng: &mut ChaCha8Rng, terms: usize, scale: f64) -> Vec<f64> {
        (0..terms).map(|_| rng.gen_range(-scale..scale)).collect()
    }

    #[test]
    fn osa_index_and_osa_nm_are_inverse() {
        // Exact integer bookkeeping: the first ten entries of Z80.28 Table 1, then a round trip far out.
        let table = [
            (0, 0),
            (1, -1),
            (1, 1),
            (2, -2),
            (2, 0),
            (2, 2),
            (3, -3),
            (3, -1),
            (3, 1),
            (3, 3),
        ];
        for (j, &nm) in table.iter().enumerate() {
            assert_eq!(osa_nm(j), nm);
        }
        for j in 0..10_000 {
            let (n, m) = osa_nm(j);
            assert_eq!(osa_index(n, m), j);
        }
        assert_eq!(n_terms_for_order(6), 28);
        assert_eq!(n_terms_for_order(MAX_RADIAL_ORDER), 66);
        assert_eq!(osa_nm(27), (6, 6));
        assert_eq!(osa_nm(28), (7, -7));
    }

    #[test]
    fn terms_to_order_6_are_orthonormal_over_the_unit_disk() {
        // Tolerance 1e-10: the quadrature is exact for these degree-12 products, so only rounding remains.
        let points = disk_quadrature(12, 32);
        for j in 0..28 {
            for k in 0..=j {
                let inner: f64 = points
                    .iter()
                    .map(|&(x, y, w)| w * zernike_value(j, x, y) * zernike_value(k, x, y))
                    .sum::<f64>()
                    / PI;
                let expected = if j == k { 1.0 } else { 0.0 };
                assert!((inner - expected).abs() < 1e-10, "<Z{j}, Z{k}> = {inner}");
            }
        }
    }

    #[test]
    fn terms_to_order_10_are_orthonormal_over_the_unit_disk() {
        // Tolerance 1e-10: exact quadrature for degree-20 products; coefficients reach ~1e4 at order 10.
        let points = disk_quadrature(16, 48);
        for j in 0..66 {
            for k in 0..=j {
                let inner: f64 = points
                    .iter()
                    .map(|&(x, y, w)| w * zernike_value(j, x, y) * zernike_value(k, x, y))
                    .sum::<f64>()
                    / PI;
                let expected = if j == k { 1.0 } else { 0.0 };
                assert!((inner - expected).abs() < 1e-10, "<Z{j}, Z{k}> = {inner}");
            }
        }
    }

    #[test]
    fn terms_match_closed_forms_of_the_standard() {
        // Tolerance 1e-12: a few roundings apart from the closed forms of Z80.28 Table 2.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..200 {
            let rho: f64 = rng.gen_range(0.0..1.0);
            let theta: f64 = rng.gen_range(0.0..2.0 * PI);
            let (x, y) = (rho * theta.cos(), rho * theta.sin());
            let r2 = rho * rho;
            let cases = [
                (0, 1.0),
                (1, 2.0 * rho * theta.sin()),
                (2, 2.0 * rho * theta.cos()),
                (3, 6f64.sqrt() * r2 * (2.0 * theta).sin()),
                (4, 3f64.sqrt() * (2.0 * r2 - 1.0)),
                (5, 6f64.sqrt() * r2 * (2.0 * theta).cos()),
                (7, 8f64.sqrt() * (3.0 * r2 * rho - 2.0 * rho) * theta.sin()),
                (12, 5f64.sqrt() * (6.0 * r2 * r2 - 6.0 * r2 + 1.0)),
                (24, 7f64.sqrt() * (20.0 * r2.powi(3) - 30.0 * r2 * r2 + 12.0 * r2 - 1.0)),
            ];
            for (j, expected) in cases {
                let got = zernike_value(j, x, y);
                assert!((got - expected).abs() < 1e-12, "Z{j}: {got} vs {expected}");
            }
        }
    }

    /// Central difference with step h: error ~h²·|∂³Z| + ε·|Z|/h, about 1e-8 here.
    fn central_difference(f: impl Fn(f64, f64) -> f64, x: f64, y: f64) -> [f64; 2] {
        let h = 1e-5;
        [
            (f(x + h, y) - f(x - h, y)) / (2.0 * h),
            (f(x, y + h) - f(x, y - h)) / (2.0 * h),
        ]
    }

    #[test]
    fn zernike_gradient_matches_central_differences() {
        // Tolerance 1e-6·(1+|g|): the finite difference itself is only good to ~1e-8 at order 10.
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..100 {
            let (x, y) = random_in_disk(&mut rng, 1.0);
            for j in 0..66 {
                let g = zernike_gradient(j, x, y);
                let fd = central_difference(|x, y| zernike_value(j, x, y), x, y);
                for axis in 0..2 {
                    let err = (g[axis] - fd[axis]).abs();
                    assert!(err < 1e-6 * (1.0 + g[axis].abs()), "j={j} axis {axis}: {g:?} vs {fd:?}");
                }
            }
        }
        // The centre needs no special case (no atan2, no division by ρ).
        assert_eq!(zernike_gradient(4, 0.0, 0.0), [0.0, 0.0]);
        let tilt = zernike_gradient(2, 0.0, 0.0);
        assert!((tilt[0] - 2.0).abs() < 1e-15 && tilt[1] == 0.0);
    }

    #[test]
    fn polynomial_gradient_matches_central_differences() {
        // Tolerance 1e-6·(1+|g|), as for the term-wise gradient.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for j in 0..66 {
            let poly = ZernikePolynomial::single_term(j);
            for _ in 0..20 {
                let (x, y) = random_in_disk(&mut rng, 1.0);
                let g = poly.gradient(x, y);
                let fd = central_difference(|x, y| poly.value(x, y), x, y);
                for axis in 0..2 {
                    let err = (g[axis] - fd[axis]).abs();
                    assert!(err < 1e-6 * (1.0 + g[axis].abs()), "j={j} axis {axis}: {g:?} vs {fd:?}");
                }
            }
        }
    }

    /// The gradient made row by row is the dot product of the gradient's coefficients with the whole monomial
    /// table, bit for bit, for every degree.
    #[test]
    fn polynomial_gradient_is_the_monomial_table_dot_product() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for terms in [1, 2, 3, 6, 10, 15, 28, 45, 66] {
            let poly = ZernikePolynomial::from_coefficients(&random_set(&mut rng, terms, 1.0));
            for _ in 0..50 {
                let (x, y) = random_in_disk(&mut rng, 1.0);
                let mut table = [0.0; N_GRADIENT_MONOMIALS];
                let len = monomial_table(x, y, poly.degree.saturating_sub(1), &mut table);
                let want = table[..len]
                    .iter()
                    .zip(&poly.gradient[..len])
                    .fold([0.0, 0.0], |[gx, gy], (m, [cx, cy])| [gx + cx * m, gy + cy * m]);
                let want = if poly.degree == 0 { [0.0; 2] } else { want };
                assert_eq!(poly.gradient(x, y), want, "{terms} terms");
            }
        }
    }

    /// The batched gradient is the one-point gradient at each point, bit for bit.
    #[test]
    fn batched_gradients_are_the_one_point_gradients() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for terms in [1, 2, 3, 6, 10, 15, 28, 45, 66] {
            let poly = ZernikePolynomial::from_coefficients(&random_set(&mut rng, terms, 1.0));
            for _ in 0..10 {
                let (mut x, mut y) = ([0.0; GRADIENT_BATCH], [0.0; GRADIENT_BATCH]);
                for b in 0..GRADIENT_BATCH {
                    (x[b], y[b]) = random_in_disk(&mut rng, 1.0);
                }
                let mut out = [[f64::NAN; 2]; GRADIENT_BATCH];
                poly.gradients(&x, &y, &mut out);
                for b in 0..GRADIENT_BATCH {
                    assert_eq!(out[b], poly.gradient(x[b], y[b]), "{terms} terms, point {b}");
                }
            }
        }
    }

    #[test]
    fn single_term_polynomial_matches_term_evaluation() {
        // Tolerance 1e-11: monomial cancellation at order 10 costs a few hundred ulps of the terms' scale.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for j in 0..66 {
            let poly = ZernikePolynomial::single_term(j);
            for _ in 0..50 {
                let (x, y) = random_in_disk(&mut rng, 1.0);
                assert!((poly.value(x, y) - zernike_value(j, x, y)).abs() < 1e-11, "j={j}");
                let (g, h) = (poly.gradient(x, y), zernike_gradient(j, x, y));
                assert!((g[0] - h[0]).abs() < 1e-10 && (g[1] - h[1]).abs() < 1e-10, "j={j}");
            }
        }
    }

    #[test]
    fn polynomial_from_coefficients_matches_sum_of_terms() {
        // Tolerance 1e-10: 66 unit-scale terms, each good to ~1e-12 after monomial expansion.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for terms in [1, 3, 6, 15, 28, 66] {
            let c = random_set(&mut rng, terms, 1.0);
            let poly = ZernikePolynomial::from_coefficients(&c);
            for _ in 0..50 {
                let (x, y) = random_in_disk(&mut rng, 1.0);
                let value: f64 = c.iter().enumerate().map(|(j, c)| c * zernike_value(j, x, y)).sum();
                let mut grad = [0.0; 2];
                for (j, c) in c.iter().enumerate() {
                    let g = zernike_gradient(j, x, y);
                    grad[0] += c * g[0];
                    grad[1] += c * g[1];
                }
                assert!((poly.value(x, y) - value).abs() < 1e-10);
                let g = poly.gradient(x, y);
                assert!((g[0] - grad[0]).abs() < 1e-9 && (g[1] - grad[1]).abs() < 1e-9);
            }
        }
        // Piston alone has zero gradient; an empty set is zero everywhere.
        assert_eq!(
            ZernikePolynomial::from_coefficients(&[3.0]).gradient(0.3, 0.2),
            [0.0; 2]
        );
        assert_eq!(ZernikePolynomial::from_coefficients(&[]).value(0.3, 0.2), 0.0);
    }

    #[test]
    fn rescaling_defocus_and_spherical_matches_closed_form() {
        // Tolerance 1e-12 µm: closed form of Annex B for C(2,0), C(4,0) evaluated two ways.
        let (c20, c40) = (1.3, -0.27);
        let mut coefficients = vec![0.0; 28];
        coefficients[4] = c20;
        coefficients[12] = c40;
        let set = ZernikeCoefficients::new(6.0, coefficients).unwrap();
        for new_d in [6.0, 5.0, 4.0, 3.0, 1.0] {
            let s: f64 = new_d / 6.0;
            let r = set.rescaled(new_d).unwrap();
            let s2 = s * s;
            let expected_c20 = s2 * c20 - 15f64.sqrt() * s2 * (1.0 - s2) * c40;
            assert!((r.get(4) - expected_c20).abs() < 1e-12, "d={new_d}");
            assert!((r.get(12) - s2 * s2 * c40).abs() < 1e-12, "d={new_d}");
            // Piston picks up the rest of the mean; nothing else appears.
            for j in (0..28).filter(|&j| j != 0 && j != 4 && j != 12) {
                assert_eq!(r.get(j), 0.0);
            }
        }
    }

    #[test]
    fn rescaling_preserves_the_physical_wavefront() {
        // Tolerance 1e-10 µm: both sides are exact polynomials of the same point, ~30 µm in size.
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for terms in [28, 66] {
            let set = ZernikeCoefficients::new(7.0, random_set(&mut rng, terms, 1.0)).unwrap();
            for new_d in [7.0, 6.0, 4.5, 2.0] {
                let small = set.rescaled(new_d).unwrap();
                assert_eq!(small.coefficients_um.len(), terms);
                for _ in 0..100 {
                    let (x, y) = random_in_disk(&mut rng, new_d / 2.0);
                    let (a, b) = (set.wavefront_um(x, y), small.wavefront_um(x, y));
                    assert!((a - b).abs() < 1e-10, "{terms} terms, d={new_d}: {a} vs {b}");
                    let (ga, gb) = (set.gradient_mrad(x, y), small.gradient_mrad(x, y));
                    assert!((ga[0] - gb[0]).abs() < 1e-9 && (ga[1] - gb[1]).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn rescaling_matches_least_squares_projection() {
        // Tolerance 1e-10 µm: independent route, projecting W(s·ρ) onto the basis by exact quadrature.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let set = ZernikeCoefficients::new(6.0, random_set(&mut rng, 66, 0.5)).unwrap();
        let s = 4.0 / 6.0;
        let closed = set.rescaled(4.0).unwrap();
        let points = disk_quadrature(16, 48);
        let poly = set.polynomial();
        for j in 0..66 {
            let projected: f64 = points
                .iter()
                .map(|&(x, y, w)| w * poly.value(s * x, s * y) * zernike_value(j, x, y))
                .sum::<f64>()
                / PI;
            assert!((projected - closed.get(j)).abs() < 1e-10, "j={j}");
        }
    }

    #[test]
    fn rescaling_in_steps_equals_rescaling_at_once_and_equal_pupil_is_identity() {
        // Tolerance 1e-12 µm: the scalings compose exactly, s = s1·s2.
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let set = ZernikeCoefficients::new(8.0, random_set(&mut rng, 28, 2.0)).unwrap();
        let same = set.rescaled(8.0).unwrap();
        for j in 0..28 {
            assert!((same.get(j) - set.get(j)).abs() < 1e-12);
        }
        let two_steps = set.rescaled(6.0).unwrap().rescaled(3.0).unwrap();
        let one_step = set.rescaled(3.0).unwrap();
        assert_eq!(two_steps.pupil_diameter_mm, 3.0);
        for j in 0..28 {
            assert!((two_steps.get(j) - one_step.get(j)).abs() < 1e-12, "j={j}");
        }
    }

    #[test]
    fn enlarging_the_pupil_is_an_error() {
        // Exact: extrapolation beyond the measured pupil is refused, as are invalid targets.
        let set = ZernikeCoefficients::zero(5.0);
        assert_eq!(
            set.rescaled(6.0),
            Err(ZernikeError::CannotEnlargePupil {
                from_mm: 5.0,
                to_mm: 6.0
            })
        );
        assert!(matches!(set.rescaled(0.0), Err(ZernikeError::PupilOutOfRange { .. })));
        assert!(matches!(
            set.rescaled(f64::NAN),
            Err(ZernikeError::PupilOutOfRange { .. })
        ));
    }

    #[test]
    fn minus_two_dioptre_sphere_gives_known_defocus() {
        // Tolerance 1e-3 µm: C(2,0) = −M·r²/(4√3) = 2·9/(4√3) = 2.598 µm, given to 3 decimals.
        let rx = Prescription {
            sphere_d: -2.0,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        };
        let set = ZernikeCoefficients::from_prescription(&rx, 6.0);
        assert!((set.get(4) - 2.598).abs() < 1e-3, "C(2,0) = {}", set.get(4));
        assert_eq!(set.get(3), 0.0);
        assert_eq!(set.get(5), 0.0);
        assert_eq!(set.coefficients_um.len(), 28);
        set.validate().unwrap();
    }

    /// Angular distance between two axes, modulo 180°.
    fn axis_distance_deg(a: f64, b: f64) -> f64 {
        let d = (a - b).rem_euclid(180.0);
        d.min(180.0 - d)
    }

    #[test]
    fn prescription_round_trips_through_zernike() {
        // Tolerance 1e-10 D and 1e-8°: only trigonometric rounding separates the two forms.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..1000 {
            let rx = Prescription {
                sphere_d: rng.gen_range(-10.0..10.0),
                cylinder_d: rng.gen_range(-5.0..5.0),
                axis_deg: rng.gen_range(0.0..=180.0),
            };
            rx.validate().unwrap();
            let pupil = rng.gen_range(2.0..8.0);
            let back = ZernikeCoefficients::from_prescription(&rx, pupil).prescription();
            // Minus-cylinder transposition of the original.
            let (sphere, cyl, axis) = if rx.cylinder_d > 0.0 {
                (rx.sphere_d + rx.cylinder_d, -rx.cylinder_d, rx.axis_deg + 90.0)
            } else {
                (rx.sphere_d, rx.cylinder_d, rx.axis_deg)
            };
            assert!((back.sphere_d - sphere).abs() < 1e-10, "{rx:?} -> {back:?}");
            assert!((back.cylinder_d - cyl).abs() < 1e-10, "{rx:?} -> {back:?}");
            assert!(axis_distance_deg(back.axis_deg, axis) < 1e-8, "{rx:?} -> {back:?}");
            assert!((0.0..180.0).contains(&back.axis_deg));
            assert!(back.cylinder_d <= 0.0);
        }
    }

    #[test]
    fn axis_wraps_into_0_180() {
        // Tolerance 1e-9: axes 180 and 0 are the same meridian; plus cylinder at 90 is minus at 0/180.
        let at = |sphere_d, cylinder_d, axis_deg| {
            let rx = Prescription {
                sphere_d,
                cylinder_d,
                axis_deg,
            };
            Prescription::from_power_vector(&rx.power_vector())
        };
        let a = at(-1.0, -2.0, 180.0);
        assert!(
            (a.axis_deg - 0.0).abs() < 1e-9 && (a.cylinder_d + 2.0).abs() < 1e-12,
            "{a:?}"
        );
        let b = at(-3.0, 1.5, 90.0);
        assert!(b.axis_deg.abs() < 1e-9, "{b:?}");
        assert!(
            (b.sphere_d + 1.5).abs() < 1e-12 && (b.cylinder_d + 1.5).abs() < 1e-12,
            "{b:?}"
        );
        let c = at(0.0, 1.0, 135.0);
        assert!((c.axis_deg - 45.0).abs() < 1e-9, "{c:?}");
        let d = at(0.0, -1.0, 179.999_999_999);
        assert!(
            d.axis_deg < 180.0 && axis_distance_deg(d.axis_deg, 180.0) < 1e-8,
            "{d:?}"
        );
        // No cylinder: axis is meaningless and reported as 0.
        let e = at(-2.0, 0.0, 73.0);
        assert_eq!((e.cylinder_d, e.axis_deg), (0.0, 0.0));
        assert!(!e.cylinder_d.is_sign_negative());
    }

    #[test]
    fn one_dioptre_defocus_has_3_mrad_slope_at_6mm_pupil_edge() {
        // Tolerance 1e-12 mrad: a 1 D vergence error tilts rays by r·D = 3 mm·1 D = 3 mrad at the edge.
        for sphere_d in [-1.0, 1.0] {
            let rx = Prescription {
                sphere_d,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            };
            let set = ZernikeCoefficients::from_prescription(&rx, 6.0);
            for theta in [0.0, 0.7, 2.0, 4.0] {
                let (x, y) = (3.0 * f64::cos(theta), 3.0 * f64::sin(theta));
                let [gx, gy] = set.gradient_mrad(x, y);
                assert!((gx.hypot(gy) - 3.0).abs() < 1e-12, "|∇W| = {}", gx.hypot(gy));
                // Myopia (S < 0, C(2,0) > 0) makes the slope point outwards.
                assert!((gx * x + gy * y).signum() == -sphere_d.signum());
                // The polynomial route agrees once divided by r_p.
                let [px, py] = set.polynomial().gradient(x / 3.0, y / 3.0);
                assert!((px / 3.0 - gx).abs() < 1e-12 && (py / 3.0 - gy).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn rms_and_order_zeroing_follow_radial_order() {
        // Tolerance 1e-12 µm: sums of a few squares.
        let c: Vec<f64> = (0..28).map(|j| 0.01 * (j as f64 + 1.0)).collect();
        let set = ZernikeCoefficients::new(6.0, c.clone()).unwrap();
        let hoa: f64 = c[6..].iter().map(|c| c * c).sum::<f64>().sqrt();
        assert!((set.rms_um(3..=MAX_RADIAL_ORDER) - hoa).abs() < 1e-12);
        assert!((set.rms_um(2..=2) - (c[3].powi(2) + c[4].powi(2) + c[5].powi(2)).sqrt()).abs() < 1e-12);
        let no_tilt = set.with_order_range_zeroed(0..=1);
        assert_eq!(&no_tilt.coefficients_um[..3], &[0.0; 3]);
        assert_eq!(&no_tilt.coefficients_um[3..], &c[3..]);
        assert_eq!(no_tilt.rms_um(0..=1), 0.0);
        // The unit-RMS normalisation means the RMS is also the quadrature RMS of the wavefront.
        let points = disk_quadrature(12, 32);
        let poly = set.with_order_range_zeroed(0..=0).polynomial();
        let mean_square: f64 = points
            .iter()
            .map(|&(x, y, w)| w * poly.value(x, y).powi(2))
            .sum::<f64>()
            / PI;
        assert!((mean_square.sqrt() - set.rms_um(1..=6)).abs() < 1e-12);
    }

    #[test]
    fn validation_rejects_bad_sets() {
        // Exact: each rule names its field.
        let mut c = vec![0.0; 28];
        c[7] = f64::NAN;
        assert_eq!(
            ZernikeCoefficients::new(6.0, c),
            Err(ZernikeError::NonFiniteCoefficient { index: 7 })
        );
        assert_eq!(
            ZernikeCoefficients::new(6.0, vec![0.0; 67]),
            Err(ZernikeError::TooManyTerms { got: 67, max: 66 })
        );
        ZernikeCoefficients::new(6.0, vec![0.0; 66]).unwrap();
        let err = ZernikeCoefficients::new(60.0, vec![0.0; 28]).unwrap_err();
        assert!(matches!(err, ZernikeError::PupilOutOfRange { value_mm, .. } if value_mm == 60.0));
        assert!(err.to_string().contains("pupil_diameter_mm"));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(ZernikeCoefficients::new(bad, vec![]).is_err(), "pupil {bad}");
        }
        let err = ZernikeCoefficients::new(6.0, vec![0.0, 51.0]).unwrap_err();
        assert!(matches!(err, ZernikeError::CoefficientOutOfRange { index: 1, .. }));
        assert!(err.to_string().contains("coefficients_um[1]"));
    }

    #[test]
    fn validation_rejects_bad_prescriptions() {
        // Exact: each rule names its field.
        let ok = Prescription {
            sphere_d: -3.0,
            cylinder_d: -1.0,
            axis_deg: 180.0,
        };
        ok.validate().unwrap();
        let err = Prescription {
            sphere_d: f64::NAN,
            ..ok
        }
        .validate()
        .unwrap_err();
        assert_eq!(err, ZernikeError::NonFinite { field: "sphere_d" });
        let err = Prescription { cylinder_d: 12.0, ..ok }.validate().unwrap_err();
        assert!(err.to_string().starts_with("cylinder_d = 12"));
        assert!(Prescription { axis_deg: 181.0, ..ok }.validate().is_err());
        assert!(Prescription { axis_deg: -1.0, ..ok }.validate().is_err());
        assert!(Prescription { sphere_d: 21.0, ..ok }.validate().is_err());
    }

    #[test]
    fn deserialisation_validates() {
        // Exact: serde round trip of valid values, rejection of invalid ones with the field named.
        let set = ZernikeCoefficients::new(6.0, vec![0.0, 0.1, -0.2, 0.3]).unwrap();
        let json = serde_json::to_string(&set).unwrap();
        assert_eq!(serde_json::from_str::<ZernikeCoefficients>(&json).unwrap(), set);
        let err =
            serde_json::from_str::<ZernikeCoefficients>(r#"{"pupil_diameter_mm": 60.0, "coefficients_um": [0.0]}"#)
                .unwrap_err();
        assert!(err.to_string().contains("pupil_diameter_mm"), "{err}");
        let rx = Prescription {
            sphere_d: -1.25,
            cylinder_d: -0.5,
            axis_deg: 90.0,
        };
        let json = serde_json::to_string(&rx).unwrap();
        assert_eq!(serde_json::from_str::<Prescription>(&json).unwrap(), rx);
        let err = serde_json::from_str::<Prescription>(r#"{"sphere_d": -1.0, "cylinder_d": -0.5, "axis_deg": 200.0}"#)
            .unwrap_err();
        assert!(err.to_string().contains("axis_deg"), "{err}");
    }
}
