//! Fraunhofer diffraction at the display's apertures (docs/design.md §2, "Wave optics").
//!
//! A circular hole of diameter a spreads a ray into the Airy pattern I(θ) ∝ [2J₁(x)/x]², x = π·a·θ/λ, first zero
//! at θ = 1.2197·λ/a, with encircled energy 1 − J₀²(x) − J₁²(x) (Born & Wolf, *Principles of Optics*, §8.5.2). A
//! square lenslet of side p spreads it by sinc²(p·θₓ/λ)·sinc²(p·θ_y/λ), sinc(t) = sin(πt)/(πt), zeros at
//! θ = k·λ/p (Goodman, *Introduction to Fourier Optics*, §4.4). Sampling a diffraction angle per sub-ray is the
//! ray-space (Wigner) approximation of the diffracted field (Zhang & Levoy 2009).
//!
//! The Bessel functions are the polynomial approximations of Abramowitz & Stegun 9.4.1–9.4.6 (|error| < 5·10⁻⁸),
//! hand-written because no small, well-kept crate offers them without pulling in a numerics framework.

use std::f64::consts::PI;

/// x/3 powers for A&S 9.4.1 and 9.4.4 (|x| ≤ 3).
fn small(x: f64, c: &[f64; 7]) -> f64 {
    let t = (x / 3.0) * (x / 3.0);
    c.iter().rev().fold(0.0, |acc, k| acc * t + k)
}

/// 3/x polynomial of A&S 9.4.3 and 9.4.6 (x ≥ 3).
fn large(x: f64, c: &[f64; 7]) -> f64 {
    let t = 3.0 / x;
    c.iter().rev().fold(0.0, |acc, k| acc * t + k)
}

/// The Bessel function J₀(x) (A&S 9.4.1, 9.4.3).
pub fn bessel_j0(x: f64) -> f64 {
    let x = x.abs();
    if x <= 3.0 {
        small(
            x,
            &[1.0, -2.2499997, 1.2656208, -0.3163866, 0.0444479, -0.0039444, 0.0002100],
        )
    } else {
        let f0 = large(
            x,
            &[
                0.79788456,
                -0.00000077,
                -0.00552740,
                -0.00009512,
                0.00137237,
                -0.00072805,
                0.00014476,
            ],
        );
        let th = x + large(
            x,
            &[
                -std::f64::consts::FRAC_PI_4,
                -0.04166397,
                -0.00003954,
                0.00262573,
                -0.00054125,
                -0.00029333,
                0.00013558,
            ],
        );
        f0 * th.cos() / x.sqrt()
    }
}

/// The Bessel function J₁(x) (A&S 9.4.4, 9.4.6).
pub fn bessel_j1(x: f64) -> f64 {
    let (s, x) = (x.signum(), x.abs());
    let v = if x <= 3.0 {
        x * small(
            x,
            &[
                0.5,
                -0.56249985,
                0.21093573,
                -0.03954289,
                0.00443319,
                -0.00031761,
                0.00001109,
            ],
        )
    } else {
        let f1 = large(
            x,
            &[
                0.79788456,
                0.00000156,
                0.01659667,
                0.00017105,
                -0.00249511,
                0.00113653,
                -0.00020033,
            ],
        );
        let th = x + large(
            x,
            &[
                -2.35619449,
                0.12499612,
                0.00005650,
                -0.00637879,
                0.00074348,
                0.00079824,
                -0.00029166,
            ],
        );
        f1 * th.cos() / x.sqrt()
    };
    s * v
}

/// The Airy pattern's relative intensity [2J₁(x)/x]² at x = π·a·θ/λ (1 at x = 0).
pub fn airy_intensity(x: f64) -> f64 {
    if x.abs() < 1e-8 {
        return 1.0;
    }
    let v = 2.0 * bessel_j1(x) / x;
    v * v
}

/// [`airy_intensity`] tabulated for the kernels' inner loops (held by [`DiffractionSampler`]): I(x) = [2J₁(x)/x]² and its derivative
/// I′(x) = −4·[2J₁(x)/x]·J₂(x)/x (from J₁′ = J₀ − J₁/x and J₂ = 2J₁/x − J₀, A&S 9.1.27) at steps of
/// 1/[`AIRY_TABLE_STEPS_PER_UNIT`] on 0 ≤ x ≤ [`AIRY_TABLE_X_MAX`], interpolated by cubic Hermite polynomials
/// (error h⁴/384·max|I⁗| < 10⁻⁹, below the Bessel approximations' own); beyond, the direct formula.
#[derive(Clone, Debug)]
pub struct AiryTable {
    /// (I, I′) at x = k/steps.
    nodes: Vec<[f64; 2]>,
}

/// Table nodes per unit of x = π·a·θ/λ.
pub const AIRY_TABLE_STEPS_PER_UNIT: usize = 64;
/// The table's reach in x (the 20th dark ring is near x = 63.6; past it lies about 1 % of the power).
pub const AIRY_TABLE_X_MAX: f64 = 64.0;

impl AiryTable {
    fn new() -> Self {
        let n = AIRY_TABLE_X_MAX as usize * AIRY_TABLE_STEPS_PER_UNIT;
        let nodes = (0..=n)
            .map(|k| {
                let x = k as f64 / AIRY_TABLE_STEPS_PER_UNIT as f64;
                if x == 0.0 {
                    return [1.0, 0.0];
                }
                let v = 2.0 * bessel_j1(x) / x;
                // J₂(x)/x: its series below x = 1 (A&S 9.1.10; the next term is below 10⁻⁹ there), where
                // 2J₁/x² − J₀/x would lose digits to cancellation.
                let j2_over_x = if x < 1.0 {
                    let q = x * x / 4.0;
                    x / 8.0 * (1.0 - q / 3.0 + q * q / 24.0 - q * q * q / 360.0 + q * q * q * q / 8640.0)
                } else {
                    (v - bessel_j0(x)) / x
                };
                [v * v, -4.0 * v * j2_over_x]
            })
            .collect();
        Self { nodes }
    }

    /// [2J₁(x)/x]², from the table where it reaches.
    #[inline]
    pub fn intensity(&self, x: f64) -> f64 {
        let x = x.abs();
        if self.covers(x) {
            self.interpolate(x)
        } else {
            airy_intensity(x)
        }
    }

    /// Whether [`Self::intensity`] at x ≥ 0 comes from the table (else from the formula).
    #[inline(always)]
    pub fn covers(&self, x: f64) -> bool {
        x * (AIRY_TABLE_STEPS_PER_UNIT as f64) < (self.nodes.len() - 1) as f64
    }

    /// The table's cubic Hermite interpolation at x ≥ 0, [`Self::intensity`] where the table [`Self::covers`] x
    /// and the last node's polynomial elsewhere (meaningless there): straight-line arithmetic the compiler
    /// vectorises, for loops that take the formula where the table does not reach.
    #[inline(always)]
    pub fn interpolate(&self, x: f64) -> f64 {
        let last = f64::from_bits(((self.nodes.len() - 1) as f64).to_bits() - 1);
        let s = (x * AIRY_TABLE_STEPS_PER_UNIT as f64).min(last);
        // SAFETY: 0 ≤ s < nodes.len() − 1 < 2³¹ (x ≥ 0; NaN is excluded by the min), so k + 1 is a node.
        let k = unsafe { s.max(0.0).to_int_unchecked::<i32>() } as usize;
        let (t, h) = (s - k as f64, 1.0 / AIRY_TABLE_STEPS_PER_UNIT as f64);
        let ([y0, m0], [y1, m1]) = unsafe { (*self.nodes.get_unchecked(k), *self.nodes.get_unchecked(k + 1)) };
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * y0
            + (t3 - 2.0 * t2 + t) * h * m0
            + (3.0 * t2 - 2.0 * t3) * y1
            + (t3 - t2) * h * m1
    }
}

/// The fraction of the Airy pattern's power within x = π·a·θ/λ: 1 − J₀²(x) − J₁²(x) (Rayleigh).
pub fn airy_encircled_energy(x: f64) -> f64 {
    let (j0, j1) = (bessel_j0(x), bessel_j1(x));
    (1.0 - j0 * j0 - j1 * j1).clamp(0.0, 1.0)
}

/// The first zero of J₁, the Airy pattern's first dark ring in x = π·a·θ/λ.
pub const AIRY_FIRST_ZERO_X: f64 = 3.831_705_970_207_512;

/// sinc²(t) = [sin(πt)/(πt)]², the one-axis intensity of a square aperture at t = p·θ/λ.
pub fn sinc2(t: f64) -> f64 {
    if t.abs() < 1e-8 {
        return 1.0;
    }
    let v = (PI * t).sin() / (PI * t);
    v * v
}

/// Draws diffraction angles by inverting tabulated cumulative distributions: the Airy radius in x (polar) and
/// one axis of sinc² in t. Tabulated once; each draw is a binary search.
#[derive(Clone, Debug)]
pub struct DiffractionSampler {
    /// (x, encircled energy) of the Airy pattern, ascending.
    airy: Cdf,
    /// The Airy pattern's intensity, for weighting pupil-sampled sub-rays.
    airy_intensity: AiryTable,
    /// (t, cumulative power) of sinc² over [−T, T], ascending.
    sinc: Cdf,
}

/// A tabulated cumulative distribution with a guide table (Chen & Asau 1974): `guide[b]` is the first entry
/// whose cumulative value reaches b/B, so inverting u searches only between `guide[⌊uB⌋]` and the next
/// guide, with the same result as a search of the whole table.
#[derive(Clone, Debug)]
struct Cdf {
    /// The table's x, ascending.
    xs: Vec<f64>,
    /// The cumulative value at each x, ascending; held apart from x so that a search touches only these.
    cs: Vec<f64>,
    guide: Vec<u32>,
    /// The table's first x and entries per unit of x (its grid is uniform in x).
    x0: f64,
    per_x: f64,
}

/// Buckets of the guide tables.
const GUIDE_BUCKETS: usize = 1 << 16;

impl Cdf {
    fn new(table: Vec<(f64, f64)>) -> Self {
        let (xs, cs): (Vec<f64>, Vec<f64>) = table.into_iter().unzip();
        let guide = (0..=GUIDE_BUCKETS)
            .map(|b| {
                let u = b as f64 / GUIDE_BUCKETS as f64;
                cs.partition_point(|&c| c < u) as u32
            })
            .collect();
        let n = xs.len() - 1;
        let (x0, x1) = (xs[0], xs[n]);
        Self {
            guide,
            x0,
            per_x: n as f64 / (x1 - x0),
            xs,
            cs,
        }
    }

    /// The cumulative value at `x`, linearly interpolated on the table's uniform grid of x (0 before its
    /// start, 1 past its end), so that inverting it with [`DiffractionSampler::invert`] gives x back.
    #[inline]
    fn at(&self, x: f64) -> f64 {
        let cs = &self.cs;
        let n = cs.len() - 1;
        let f = (x - self.x0) * self.per_x;
        if f.is_nan() || f <= 0.0 {
            return 0.0;
        }
        if f >= n as f64 {
            return 1.0;
        }
        let k = f as usize;
        let (c0, c1) = (cs[k], cs[k + 1]);
        c0 + (c1 - c0) * (f - k as f64)
    }

    /// The first index whose cumulative value is ≥ u (the table's length if none).
    #[inline]
    fn first_at_least(&self, u: f64) -> usize {
        let b = ((u * GUIDE_BUCKETS as f64) as usize).min(GUIDE_BUCKETS - 1);
        let (lo, hi) = (self.guide[b] as usize, self.guide[b + 1] as usize);
        lo + self.cs[lo..hi].partition_point(|&c| c < u)
    }
}

/// How far the tabulated distributions reach: x ≤ 60 keeps 99.3 % of the Airy power, |t| ≤ 30 keeps 99.3 % of a
/// sinc² axis; the rest (wide-angle tails far outside any pupil) is dropped and the tables renormalised.
const AIRY_X_MAX: f64 = 60.0;
pub const SINC_T_MAX: f64 = 30.0;
const TABLE_STEPS: usize = 24_000;

impl Default for DiffractionSampler {
    fn default() -> Self {
        Self::new()
    }
}

impl DiffractionSampler {
    /// The process's one sampler, tabulated on first use (the tables are the same for every build).
    pub fn shared() -> &'static Self {
        static SHARED: std::sync::OnceLock<DiffractionSampler> = std::sync::OnceLock::new();
        SHARED.get_or_init(Self::new)
    }

    /// Tabulates both distributions and the Airy intensity.
    pub fn new() -> Self {
        let airy_total = airy_encircled_energy(AIRY_X_MAX);
        let airy = (0..=TABLE_STEPS)
            .map(|k| {
                let x = AIRY_X_MAX * k as f64 / TABLE_STEPS as f64;
                (x, airy_encircled_energy(x) / airy_total)
            })
            .collect();
        // Trapezoidal cumulative of sinc² on a fine grid (its antiderivative has no elementary form).
        let h = 2.0 * SINC_T_MAX / TABLE_STEPS as f64;
        let mut sinc = Vec::with_capacity(TABLE_STEPS + 1);
        let mut acc = 0.0;
        let mut prev = sinc2(-SINC_T_MAX);
        sinc.push((-SINC_T_MAX, 0.0));
        for k in 1..=TABLE_STEPS {
            let t = -SINC_T_MAX + h * k as f64;
            let v = sinc2(t);
            acc += 0.5 * (prev + v) * h;
            prev = v;
            sinc.push((t, acc));
        }
        for e in &mut sinc {
            e.1 /= acc;
        }
        Self {
            airy: Cdf::new(airy),
            airy_intensity: AiryTable::new(),
            sinc: Cdf::new(sinc),
        }
    }

    /// The tabulated Airy intensity [2J₁(x)/x]² (64 KiB, built with the sampler).
    pub fn airy_table(&self) -> &AiryTable {
        &self.airy_intensity
    }

    #[inline]
    fn invert(cdf: &Cdf, u: f64) -> f64 {
        let k = cdf.first_at_least(u).clamp(1, cdf.cs.len() - 1);
        let ((x0, c0), (x1, c1)) = ((cdf.xs[k - 1], cdf.cs[k - 1]), (cdf.xs[k], cdf.cs[k]));
        if c1 > c0 {
            x0 + (x1 - x0) * (u - c0) / (c1 - c0)
        } else {
            x0
        }
    }

    /// The Airy radius x = π·a·θ/λ whose encircled energy is `u` ∈ [0, 1).
    pub fn airy_radius(&self, u: f64) -> f64 {
        Self::invert(&self.airy, u)
    }

    /// The sinc² coordinate t = p·θ/λ whose cumulative power is `u` ∈ [0, 1).
    pub fn sinc_coordinate(&self, u: f64) -> f64 {
        Self::invert(&self.sinc, u)
    }

    /// The cumulative power of one sinc² axis at `t` (0 below −T, 1 above T).
    pub fn sinc_cdf(&self, t: f64) -> f64 {
        self.sinc.at(t)
    }

    /// A sinc² coordinate drawn from the distribution restricted to [lo, hi], with the power it holds:
    /// (t, P(lo ≤ t ≤ hi)), or `None` when the interval holds none. Drawing from the restriction and weighting
    /// by its power is importance sampling of the whole distribution over an integrand that vanishes outside
    /// the interval (the same expectation with every draw inside it).
    pub fn sinc_coordinate_within(&self, lo: f64, hi: f64, u: f64) -> Option<(f64, f64)> {
        Self::draw_within(&self.sinc, lo, hi, u)
    }

    /// A coordinate drawn from `cdf`'s distribution restricted to [lo, hi], with the power it holds (see
    /// [`Self::sinc_coordinate_within`]).
    #[inline]
    fn draw_within(cdf: &Cdf, lo: f64, hi: f64, u: f64) -> Option<(f64, f64)> {
        let c_lo = cdf.at(lo);
        let mass = cdf.at(hi) - c_lo;
        if mass <= 0.0 {
            return None;
        }
        Some((Self::invert(cdf, c_lo + u * mass).clamp(lo, hi), mass))
    }

    /// Pupil-plane millimetres per unit of the lenslet pattern's coordinate t = p·θ/λ, `distance_mm` away.
    fn lenslet_scale(p_mm: f64, wavelength_nm: f64, distance_mm: f64) -> f64 {
        wavelength_nm * 1e-6 * distance_mm / p_mm
    }

    /// Pupil-plane millimetres per unit of the Airy coordinate x = π·a·θ/λ, `distance_mm` away.
    fn airy_scale(a_mm: f64, wavelength_nm: f64, distance_mm: f64) -> f64 {
        wavelength_nm * 1e-6 * distance_mm / (PI * a_mm)
    }

    /// The Airy coordinates of the annulus around a ray aimed at `chief` that can reach a pupil of radius `r_p`
    /// (`scale` from [`Self::airy_scale`]): (lo, hi, distance of the chief from the pupil's centre).
    fn airy_annulus(scale: f64, chief: [f64; 2], r_p: f64) -> (f64, f64, f64) {
        let c = chief[0].hypot(chief[1]);
        ((c - r_p).max(0.0) / scale, (c + r_p) / scale, c)
    }

    /// A diffraction angle (radians) for a square lenslet of side `p_mm` whose undiffracted ray meets the pupil
    /// plane, `distance_mm` away, at `chief` (mm from the pupil's centre), drawn among the angles that enter the
    /// pupil of radius `r_p`, with the power they hold: x from sinc² restricted to the pupil's extent in x, y
    /// from sinc² restricted to the pupil's chord at that x. Weighting by the power is importance sampling of
    /// [`Self::lenslet_angle`] times the pupil's indicator: the same expectation, every draw inside the pupil.
    #[allow(clippy::too_many_arguments)]
    pub fn lenslet_angle_into_pupil(
        &self,
        p_mm: f64,
        wavelength_nm: f64,
        distance_mm: f64,
        chief: [f64; 2],
        r_p: f64,
        u1: f64,
        u2: f64,
    ) -> Option<([f64; 2], f64)> {
        // t = p·θ/λ, and the pupil plane's point is chief + distance·θ = chief + t·(λ·distance/p).
        let scale = Self::lenslet_scale(p_mm, wavelength_nm, distance_mm);
        let (tx, mx) = self.sinc_coordinate_within((-r_p - chief[0]) / scale, (r_p - chief[0]) / scale, u1)?;
        let x = chief[0] + tx * scale;
        let half = (r_p * r_p - x * x).max(0.0).sqrt();
        let (ty, my) = self.sinc_coordinate_within((-half - chief[1]) / scale, (half - chief[1]) / scale, u2)?;
        let k = scale / distance_mm;
        Some(([tx * k, ty * k], mx * my))
    }

    /// A diffraction angle (radians) for a circular hole of diameter `a_mm` whose undiffracted ray meets the
    /// pupil plane at `chief`, drawn among the angles that enter the pupil of radius `r_p`, with the power they
    /// hold: the Airy radius restricted to the annulus that can reach the pupil, then the azimuth restricted to
    /// the arc of that circle inside it (law of cosines). Importance sampling of [`Self::pinhole_angle`] times
    /// the pupil's indicator, as for lenslets.
    #[allow(clippy::too_many_arguments)]
    pub fn pinhole_angle_into_pupil(
        &self,
        a_mm: f64,
        wavelength_nm: f64,
        distance_mm: f64,
        chief: [f64; 2],
        r_p: f64,
        u1: f64,
        u2: f64,
    ) -> Option<([f64; 2], f64)> {
        // x = π·a·θ/λ; the pupil-plane offset is ρ = distance·θ = x·scale.
        let scale = Self::airy_scale(a_mm, wavelength_nm, distance_mm);
        let (lo, hi, c) = Self::airy_annulus(scale, chief, r_p);
        let (x, mass) = Self::draw_within(&self.airy, lo, hi, u1)?;
        let rho = x * scale;
        // |chief + ρ·(cos ψ, sin ψ)| ≤ r_p ⟺ cos(ψ − ψ_c) ≤ κ, with ψ_c the chief's direction.
        let (psi, arc) = if rho + c <= r_p || c == 0.0 {
            (2.0 * PI * u2, 1.0)
        } else {
            let kappa = (r_p * r_p - c * c - rho * rho) / (2.0 * rho * c);
            if kappa <= -1.0 {
                return None;
            }
            let half = PI - kappa.min(1.0).acos();
            let psi_c = chief[1].atan2(chief[0]);
            (psi_c + PI + half * (2.0 * u2 - 1.0), half / PI)
        };
        let theta = rho / distance_mm;
        let (s, co) = psi.sin_cos();
        Some(([theta * co, theta * s], mass * arc))
    }

    /// An upper bound on the power of a square lenslet's (`lenslet`) or a circular hole's pattern that enters
    /// the pupil of radius `r_p` from a ray aimed at `chief` (mm from the pupil's centre), `distance_mm` away:
    /// the power in the pupil's bounding square (lenslet) or in the annulus that can reach it (hole).
    pub fn pupil_power_bound(
        &self,
        lenslet: bool,
        a_mm: f64,
        wavelength_nm: f64,
        distance_mm: f64,
        chief: [f64; 2],
        r_p: f64,
    ) -> f64 {
        if lenslet {
            let scale = Self::lenslet_scale(a_mm, wavelength_nm, distance_mm);
            let axis = |c: f64| self.sinc.at((r_p - c) / scale) - self.sinc.at((-r_p - c) / scale);
            axis(chief[0]) * axis(chief[1])
        } else {
            let (lo, hi, _) = Self::airy_annulus(Self::airy_scale(a_mm, wavelength_nm, distance_mm), chief, r_p);
            self.airy.at(hi) - self.airy.at(lo)
        }
    }

    /// A diffraction angle (radians, x and y) for a circular hole of diameter `a_mm` at `wavelength_nm`, from
    /// two uniform numbers in [0, 1).
    pub fn pinhole_angle(&self, a_mm: f64, wavelength_nm: f64, u1: f64, u2: f64) -> [f64; 2] {
        let theta = self.airy_radius(u1) * wavelength_nm * 1e-6 / (PI * a_mm);
        let (s, c) = (2.0 * PI * u2).sin_cos();
        [theta * c, theta * s]
    }

    /// A diffraction angle (radians, x and y) for a square lenslet of side `p_mm` at `wavelength_nm`.
    pub fn lenslet_angle(&self, p_mm: f64, wavelength_nm: f64, u1: f64, u2: f64) -> [f64; 2] {
        let k = wavelength_nm * 1e-6 / p_mm;
        [self.sinc_coordinate(u1) * k, self.sinc_coordinate(u2) * k]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_guide_table_finds_what_a_search_of_the_whole_table_finds() {
        let sampler = DiffractionSampler::new();
        for cdf in [&sampler.airy, &sampler.sinc] {
            for k in 0..20_000 {
                // Evenly spread values, the bucket edges themselves, and the ends.
                let u = match k % 3 {
                    0 => k as f64 / 20_000.0,
                    1 => (k % GUIDE_BUCKETS) as f64 / GUIDE_BUCKETS as f64,
                    _ => 1.0 - 1e-12 * k as f64,
                };
                assert_eq!(cdf.first_at_least(u), cdf.cs.partition_point(|&c| c < u), "u = {u}");
            }
        }
    }

    /// Bessel's integral J_n(x) = (1/π)∫₀^π cos(nτ − x sin τ) dτ by Simpson's rule: an independent evaluation.
    fn bessel_integral(n: f64, x: f64) -> f64 {
        let m = 4000;
        let h = PI / m as f64;
        let f = |t: f64| (n * t - x * t.sin()).cos();
        let mut s = f(0.0) + f(PI);
        for k in 1..m {
            s += if k % 2 == 1 { 4.0 } else { 2.0 } * f(k as f64 * h);
        }
        s * h / 3.0 / PI
    }

    #[test]
    fn the_airy_tables_slopes_are_the_intensitys_finite_differences() {
        // I′ at every node (the series of J₂/x below 1, the Bessel formula above) against a central difference
        // of the direct intensity, whose error (δ²/6·I‴ and the approximations' 10⁻⁸/δ) stays below 10⁻⁵.
        let table = DiffractionSampler::shared().airy_table();
        let delta = 1e-3;
        for (k, &[y, m]) in table.nodes.iter().enumerate().skip(1).step_by(7) {
            let x = k as f64 / AIRY_TABLE_STEPS_PER_UNIT as f64;
            assert_eq!(y, airy_intensity(x));
            let fd = (airy_intensity(x + delta) - airy_intensity(x - delta)) / (2.0 * delta);
            assert!((fd - m).abs() < 1e-5, "I′({x}) = {m}, difference {fd}");
        }
    }

    #[test]
    fn the_airy_table_is_the_airy_intensity() {
        // Between the nodes and beyond the table, on both sides of zero. Within the node interval after x = 3,
        // where A&S switch from 9.4.4 to 9.4.6, the direct formula jumps by about 10⁻⁸ and the table does not.
        let table = DiffractionSampler::shared().airy_table();
        let (mut worst, mut at_switch) = (0f64, 0f64);
        let h = 1.0 / AIRY_TABLE_STEPS_PER_UNIT as f64;
        for k in 0..60_000 {
            let x = k as f64 * 0.001_234_5;
            for x in [x, -x] {
                let err = (table.intensity(x) - airy_intensity(x)).abs();
                if (3.0..3.0 + h).contains(&x.abs()) {
                    at_switch = at_switch.max(err);
                } else {
                    worst = worst.max(err);
                }
            }
        }
        assert!(worst < 2e-9, "worst difference {worst:e}");
        assert!(at_switch < 1e-8, "worst difference after x = 3: {at_switch:e}");
        assert_eq!(table.intensity(70.3), airy_intensity(70.3));
        assert_eq!(table.intensity(0.0), 1.0);
    }

    #[test]
    fn the_airy_tables_branch_free_interpolation_is_its_intensity_where_it_covers() {
        let table = DiffractionSampler::shared().airy_table();
        let edge = AIRY_TABLE_X_MAX;
        let below = f64::from_bits(edge.to_bits() - 1);
        for x in (0..70_000).map(|k| k as f64 * 0.000_937).chain([0.0, 1.0, below]) {
            assert!(table.covers(x) == (x < edge), "covers({x})");
            if table.covers(x) {
                assert_eq!(table.interpolate(x).to_bits(), table.intensity(x).to_bits(), "x = {x}");
            } else {
                assert!(table.interpolate(x).is_finite(), "x = {x}");
            }
        }
        // The formula past the table's reach.
        assert!(!table.covers(edge) && !table.covers(1e300) && table.interpolate(1e300).is_finite());
    }

    #[test]
    fn bessel_functions_match_bessels_integral() {
        // A&S 9.4 quotes |ε| ≤ 5e-8 for J₀ and 1.3e-8·x for J₁/x; 2e-7 covers both over 0..40.
        for k in 0..400 {
            let x = 0.1 * k as f64;
            assert!((bessel_j0(x) - bessel_integral(0.0, x)).abs() < 2e-7, "J0({x})");
            assert!((bessel_j1(x) - bessel_integral(1.0, x)).abs() < 2e-7, "J1({x})");
        }
        // Tabulated values (A&S Table 9.1): J0(1) = 0.7651976866, J1(5) = −0.3275791376.
        assert!((bessel_j0(1.0) - 0.765_197_686_6).abs() < 1e-7);
        assert!((bessel_j1(5.0) + 0.327_579_137_6).abs() < 1e-7);
    }

    #[test]
    fn the_airy_first_zero_is_at_1_22_lambda_over_a() {
        // Bisection on J₁ between 3 and 4.5 finds the first dark ring; in angle that is 1.2197 λ/a.
        let (mut lo, mut hi) = (3.0, 4.5);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if bessel_j1(mid) > 0.0 {
                lo = mid
            } else {
                hi = mid
            }
        }
        assert!((lo - AIRY_FIRST_ZERO_X).abs() < 1e-6, "{lo}");
        assert!((lo / PI - 1.2197).abs() < 1e-4);
        assert!(airy_intensity(lo) < 1e-12);
        // For the 33 µm hole at 550 nm: 20.3 mrad, the figure quoted in docs/design.md.
        let theta = lo / PI * 550e-6 / 0.033;
        assert!((theta - 0.02033).abs() < 1e-4, "{theta}");
    }

    #[test]
    fn the_airy_disc_holds_83_8_percent_of_the_power() {
        // Rayleigh's closed form against direct radial quadrature of the intensity: the total of
        // ∫₀^∞ [2J₁(x)/x]² x dx is 2, so EE(x₀) = ½∫₀^x₀ [2J₁(x)/x]² x dx.
        let m = 20_000;
        let h = AIRY_FIRST_ZERO_X / m as f64;
        let integrand = |x: f64| airy_intensity(x) * x;
        let mut s = integrand(0.0) + integrand(AIRY_FIRST_ZERO_X);
        for k in 1..m {
            s += if k % 2 == 1 { 4.0 } else { 2.0 } * integrand(k as f64 * h);
        }
        let quadrature = 0.5 * s * h / 3.0;
        let closed = airy_encircled_energy(AIRY_FIRST_ZERO_X);
        assert!((quadrature - 0.8378).abs() < 1e-3, "{quadrature}");
        assert!((closed - quadrature).abs() < 1e-6, "{closed} vs {quadrature}");
    }

    #[test]
    fn sinc_squared_vanishes_at_multiples_of_lambda_over_p() {
        for k in 1..6 {
            assert!(sinc2(k as f64) < 1e-28, "{k}");
        }
        assert!((sinc2(0.5) - 4.0 / (PI * PI)).abs() < 1e-12);
    }

    #[test]
    fn sampled_angles_follow_the_patterns() {
        let s = DiffractionSampler::new();
        let n = 20_000;
        // Stratified uniforms: the fraction of draws inside the first dark ring is the encircled energy there.
        let inside = (0..n)
            .filter(|k| s.airy_radius((*k as f64 + 0.5) / n as f64) <= AIRY_FIRST_ZERO_X)
            .count() as f64
            / n as f64;
        let expected = airy_encircled_energy(AIRY_FIRST_ZERO_X) / airy_encircled_energy(AIRY_X_MAX);
        assert!((inside - expected).abs() < 1e-3, "{inside} vs {expected}");
        // sinc²: the central lobe |t| < 1 holds 90.3 % of one axis's power (∫₋₁¹ sinc² = 0.9028).
        let central = (0..n)
            .filter(|k| s.sinc_coordinate((*k as f64 + 0.5) / n as f64).abs() < 1.0)
            .count() as f64
            / n as f64;
        assert!((central - 0.9028 / 0.9966).abs() < 3e-3, "{central}");
        // Restricted to [0.5, 2]: the draws stay inside, the power is ∫ sinc² over it (Simpson, independent of
        // the table), and the draws' fraction below 1 is that interval's share of it.
        let simpson = |lo: f64, hi: f64| {
            let m = 2000;
            let h = (hi - lo) / m as f64;
            let mut acc = sinc2(lo) + sinc2(hi);
            for k in 1..m {
                acc += if k % 2 == 1 { 4.0 } else { 2.0 } * sinc2(lo + k as f64 * h);
            }
            acc * h / 3.0
        };
        let total = simpson(-SINC_T_MAX, SINC_T_MAX);
        let draws: Vec<(f64, f64)> = (0..n)
            .map(|k| {
                s.sinc_coordinate_within(0.5, 2.0, (k as f64 + 0.5) / n as f64)
                    .expect("power inside")
            })
            .collect();
        assert!(draws.iter().all(|d| (0.5..=2.0).contains(&d.0)));
        assert!((draws[0].1 - simpson(0.5, 2.0) / total).abs() < 1e-5, "{}", draws[0].1);
        let below = draws.iter().filter(|d| d.0 < 1.0).count() as f64 / n as f64;
        assert!((below - simpson(0.5, 1.0) / simpson(0.5, 2.0)).abs() < 1e-3, "{below}");
        assert!((s.sinc_cdf(0.0) - 0.5).abs() < 1e-9 && s.sinc_cdf(-40.0) == 0.0 && s.sinc_cdf(40.0) == 1.0);
        assert!(s.sinc_coordinate_within(31.0, 40.0, 0.5).is_none());
        // An angle for a 80 µm hole at 520 nm has the radius the table gives.
        let a = s.pinhole_angle(0.08, 520.0, 0.5, 0.25);
        let r = s.airy_radius(0.5) * 520e-6 / (PI * 0.08);
        assert!((a[0].hypot(a[1]) - r).abs() < 1e-15);
    }

    /// Moments (power, mean x, mean y, mean r²) of the light entering a pupil of radius 3 mm at 500 mm from a
    /// ray aimed at `chief`: by plain draws of the pattern with the pupil's rejection, and by the pupil-aimed
    /// draws weighted by their power. Returns both, each as power-weighted sums / draws.
    fn pupil_moments(pinhole: bool, chief: [f64; 2], n: usize) -> ([f64; 4], [f64; 4]) {
        let s = DiffractionSampler::shared();
        let (a, lambda, d, r_p) = (if pinhole { 0.15 } else { 1.0 }, 550.0, 500.0, 3.0);
        let mut rng = crate::physics::transport::rng::SplitMix64(7);
        let (mut plain, mut aimed) = ([0.0; 4], [0.0; 4]);
        let add = |acc: &mut [f64; 4], theta: [f64; 2], w: f64| {
            let (x, y) = (chief[0] + d * theta[0], chief[1] + d * theta[1]);
            acc[0] += w;
            acc[1] += w * x;
            acc[2] += w * y;
            acc[3] += w * (x * x + y * y);
        };
        for _ in 0..n {
            let (u1, u2) = (rng.next_f64(), rng.next_f64());
            let theta = if pinhole {
                s.pinhole_angle(a, lambda, u1, u2)
            } else {
                s.lenslet_angle(a, lambda, u1, u2)
            };
            let (x, y) = (chief[0] + d * theta[0], chief[1] + d * theta[1]);
            if x * x + y * y <= r_p * r_p {
                add(&mut plain, theta, 1.0);
            }
            let (u1, u2) = (rng.next_f64(), rng.next_f64());
            let drawn = if pinhole {
                s.pinhole_angle_into_pupil(a, lambda, d, chief, r_p, u1, u2)
            } else {
                s.lenslet_angle_into_pupil(a, lambda, d, chief, r_p, u1, u2)
            };
            if let Some((theta, w)) = drawn {
                let (x, y) = (chief[0] + d * theta[0], chief[1] + d * theta[1]);
                assert!(
                    x * x + y * y <= r_p * r_p * (1.0 + 1e-9),
                    "an aimed draw missed the pupil: {x}, {y}"
                );
                add(&mut aimed, theta, w);
            }
        }
        (plain.map(|v| v / n as f64), aimed.map(|v| v / n as f64))
    }

    #[test]
    fn pupil_aimed_draws_carry_the_light_plain_draws_carry() {
        // Chief rays inside the pupil, at its edge and outside it (where only the pattern's tail enters): the
        // power entering and its first and second moments agree within the plain draws' sampling error.
        for pinhole in [false, true] {
            for chief in [[0.4, -0.2], [2.8, 1.1], [4.5, -3.0], [-7.0, 0.5]] {
                let (plain, aimed) = pupil_moments(pinhole, chief, 400_000);
                let p = plain[0];
                let lenslet = !pinhole;
                let bound = DiffractionSampler::shared().pupil_power_bound(
                    lenslet,
                    if pinhole { 0.15 } else { 1.0 },
                    550.0,
                    500.0,
                    chief,
                    3.0,
                );
                assert!(bound >= aimed[0] && bound <= 1.0, "bound {bound} < power {}", aimed[0]);
                // Four binomial standard errors of the plain estimate of the power (where the tail enters, a
                // few in 10⁴, that is a quarter of the power itself).
                let tol = 4.0 * (p * (1.0 - p) / 400_000.0).sqrt();
                assert!(
                    (aimed[0] - p).abs() < tol,
                    "pinhole {pinhole}, chief {chief:?}: power {} vs {p}",
                    aimed[0]
                );
                for k in 1..4 {
                    let scale = if k == 3 { 9.0 } else { 3.0 };
                    assert!(
                        (aimed[k] - plain[k]).abs() < scale * tol,
                        "pinhole {pinhole}, chief {chief:?}: moment {k} {} vs {}",
                        aimed[k],
                        plain[k]
                    );
                }
            }
        }
    }
}
