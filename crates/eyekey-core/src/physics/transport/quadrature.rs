//! Lenslet kernels by deterministic quadrature (docs/design.md §2.7): no sub-ray is drawn, so the same eye, display
//! and wavelength always give the same kernels, and they carry no sampling noise.
//!
//! A lenslet collimates: the light of sample (view v, block m over) that leaves the lenslet at u (uniform over
//! its side A) crosses the pupil plane at P = u + c + q, where c is the chief ray's crossing
//! ([`super::shift_invariant`]) and q = −(d/g)·j + d·θ is independent of u: the screen pixel's box (width
//! w = p_s·d/g at the pupil) convolved with the lenslet's Fraunhofer pattern, sinc² per axis with d·θ in units of
//! b = λ·d/A. Per axis q has the density r(q) = [F((q + w/2)/b) − F((q − w/2)/b)]/w, F the sinc² cumulative
//! ([`DiffractionSampler::sinc_cdf`], the table the sampled kernels draw from). The sub-ray lands at
//! f = (u − m·p_h)/pix + s(P), s = d·∇W(P) in retinal pixels (Eq. 9), and is splatted bilinearly. So a view's
//! kernel is
//!
//! K(X, Y) = ∫_pupil dP Π_axis (1/A)∫ du r(P − u − c) hat(f(u, P) − X),
//!
//! and because u, r and the bilinear hat all factor per axis, the inner integral is a product of two one-axis
//! deposits D(δ, φ)[i], δ = P − c, φ the fractional landing of the lenslet's edge, i the tap. D is exact in
//! closed form from r's first two antiderivatives (the hat is linear between its kinks), tabulated once per
//! display, wavelength, distance and cell size, each entry averaged over a cell in δ ([`AxisTable`]).
//!
//! The pupil integral is a midpoint rule over square cells of side b, each cell's deposit the product of its two
//! axes' weighted means ([`PupilCells`]). Where the landing does not move across a cell, the cell-averaged table
//! makes this exact: x's deposit depends on P_x alone and y's on P_y alone. Where the wavefront curves, each axis
//! is seen at n points across the cell on the line through its centroid (n doubling until the landing moves
//! ≤ 0.25 retinal pixel between neighbours, the table averaged over a point's share): a curvature along the axes
//! (defocus, and so an accommodation sweep; astigmatism at 0°) keeps x's landing a function of P_x, which the
//! points follow however fast it moves. A curvature across the axes (∂s_x/∂P_y: oblique astigmatism, coma) is not
//! followed, and the cells halve until it moves the landing ≤ 0.25 pixel across one. A cell the pupil's edge cuts
//! is split where the landing moves over a pixel along an axis across it. Away from a view's core (its lenslet,
//! screen pixel and two diffraction orders), where only the smooth tails of r reach, cells of four by four are
//! taken as one. Each axis's deposits depend on the view's and the block's index along that axis only, so they are
//! computed once per pair and shared by every view and block across ([`AxisDeposits`]).

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;

use super::byte_cache::ByteBoundedCache;
use super::shift_invariant::{KernelBox, ViewKernel};
use super::trace::{floor, Tracer};
use crate::physics::diffraction::DiffractionSampler;

/// Table nodes per retinal pixel of the landing's fraction φ.
const PHI_STEPS: usize = 32;
/// Fine cells per coarse cell along each axis.
const COARSE: usize = 4;
/// Fine cells per unit of b (the sinc² pattern's first zero at the pupil).
const CELLS_PER_B: f64 = 1.0;
/// The most the landing may move between a cell's neighbouring points along an axis, retinal pixels (more points
/// where it moves faster, up to MAX_POINTS_PER_AXIS).
const MAX_SHIFT_PER_CELL: f64 = 0.25;
/// The most a fine cell may move the landing across the axes (which its points do not follow), retinal pixels:
/// where it moves faster the cells are halved, up to MAX_HALVINGS times. At 0.125 a target's view of its own frames
/// comes 0.10–0.13 % from converged on `secure` and `lenslet` instead of 0.16–0.24 %, but the population's
/// astigmatism halves their cells more: a 1,000-person `secure` evaluation took 342 s instead of 187 s
/// (docs/design.md §2.7).
const MAX_SHIFT_ACROSS_CELL: f64 = 0.25;
const MAX_HALVINGS: usize = 3;
/// The most points a fine cell is seen at along each axis.
const MAX_POINTS_PER_AXIS: usize = 16;
/// The most cells per axis a fine cell that the pupil's edge cuts is taken as, and the most the landing may move
/// along an axis across one of them, retinal pixels.
const EDGE_SPLIT: usize = 4;
const EDGE_MOTION: f64 = 1.0;
/// Table nodes of δ per unit of b.
const NODES_PER_B: usize = 12;
/// The most memory the process's axis tables may hold; the oldest go first.
const TABLE_CACHE_BYTES: usize = 64 << 20;

/// One axis of a lenslet's light, as the quadrature needs it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct AxisGeometry {
    /// The lenslet's side A, mm.
    pub a: f64,
    /// The screen pixel's width at the pupil, w = p_s·d/g, mm.
    pub w: f64,
    /// Pupil-plane millimetres per unit of the sinc² coordinate, b = λ·d/A.
    pub b: f64,
    /// A retinal pixel, mm.
    pub pix: f64,
    /// The pupil cells' side, mm: the table holds each deposit averaged over a cell.
    pub cell: f64,
}

impl AxisGeometry {
    /// The half-width of δ beyond which no light lands: the sinc² table's reach, the screen pixel and the
    /// lenslet.
    fn reach(&self) -> f64 {
        crate::physics::diffraction::SINC_T_MAX * self.b + 0.5 * (self.w + self.a)
    }

    /// Taps of one deposit: the lenslet spans A/pix retinal pixels, and a bilinear hat reaches one either side.
    fn taps(&self) -> usize {
        (self.a / self.pix - 1e-9).ceil().max(0.0) as usize + 2
    }

    /// The half-width of a view's core in δ: its lenslet, its screen pixel and two diffraction orders.
    fn core(&self) -> f64 {
        0.5 * (self.a + self.w) + 2.0 * self.b
    }
}

/// D(δ, φ)[i] on a grid of δ (uniform over ±reach) and φ ∈ [0, 1] (both ends), with r's marginal
/// through the lenslet, r_A(δ) = Σ_i D(δ, φ)[i] = (1/A)∫ r(δ − u) du.
pub(super) struct AxisTable {
    geometry: AxisGeometry,
    d0: f64,
    per_mm: f64,
    n_delta: usize,
    taps: usize,
    /// `[δ][φ][tap]`.
    w: Vec<f32>,
    power: Vec<f64>,
}

/// r's antiderivatives on a fine grid: R₁(q) = ∫ r, R₂(q) = ∫ R₁, for ∫ r and ∫ q·r over any interval.
struct Antiderivatives {
    q0: f64,
    per_q: f64,
    r1: Vec<f64>,
    r2: Vec<f64>,
}

impl Antiderivatives {
    fn new(g: &AxisGeometry, sampler: &DiffractionSampler, reach: f64) -> Self {
        let dq = g.b.min(g.w).min(g.a) / 64.0;
        let q0 = -reach - g.a;
        let n = ((2.0 * (reach + g.a)) / dq).ceil() as usize + 1;
        let r = |q: f64| (sampler.sinc_cdf((q + 0.5 * g.w) / g.b) - sampler.sinc_cdf((q - 0.5 * g.w) / g.b)) / g.w;
        let (mut r1, mut r2) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let (mut prev, mut acc1, mut acc2) = (r(q0), 0.0, 0.0);
        r1.push(0.0);
        r2.push(0.0);
        for k in 1..n {
            let v = r(q0 + k as f64 * dq);
            let next1 = acc1 + 0.5 * (prev + v) * dq;
            acc2 += 0.5 * (acc1 + next1) * dq;
            acc1 = next1;
            prev = v;
            r1.push(acc1);
            r2.push(acc2);
        }
        Self {
            q0,
            per_q: 1.0 / dq,
            r1,
            r2,
        }
    }

    /// (R₁(q), R₂(q)), linearly interpolated (constant before the grid, extrapolated past it: r is 0 there).
    fn at(&self, q: f64) -> (f64, f64) {
        let f = (q - self.q0) * self.per_q;
        let n = self.r1.len() - 1;
        if f <= 0.0 {
            return (0.0, 0.0);
        }
        if f >= n as f64 {
            let past = (f - n as f64) / self.per_q;
            return (self.r1[n], self.r2[n] + self.r1[n] * past);
        }
        let k = f as usize;
        let t = f - k as f64;
        (
            self.r1[k] + t * (self.r1[k + 1] - self.r1[k]),
            self.r2[k] + t * (self.r2[k + 1] - self.r2[k]),
        )
    }

    /// (∫_lo^hi r(q) dq, ∫_lo^hi q·r(q) dq), the second by parts: [q·R₁ − R₂].
    fn moments(&self, lo: f64, hi: f64) -> (f64, f64) {
        let ((a1, a2), (b1, b2)) = (self.at(lo), self.at(hi));
        (b1 - a1, (hi * b1 - b2) - (lo * a1 - a2))
    }
}

impl AxisTable {
    /// Tabulates the deposits for `g`, each averaged over a cell of `g.cell` (a few milliseconds): nodes b/12
    /// apart in δ, each the mean over the cell about it by Gauss–Legendre's three points on each quarter of b
    /// (D is smooth on the scale of b: the sinc² pattern blurs every edge by that much).
    pub(super) fn new(g: AxisGeometry, sampler: &DiffractionSampler) -> Self {
        let reach = g.reach();
        let anti = Antiderivatives::new(&g, sampler, reach + g.cell);
        let step = g.b / NODES_PER_B as f64;
        let n_delta = (2.0 * reach / step).ceil() as usize + 1;
        let taps = g.taps();
        let stride = (PHI_STEPS + 1) * taps;
        let span = g.a / g.pix;
        let segments = (4.0 * g.cell / g.b).ceil().max(1.0) as usize;
        let seg = g.cell / segments as f64;
        // Gauss–Legendre's three nodes and weights on [−1, 1].
        let x3 = (0.6f64).sqrt();
        let rule = [(-x3, 5.0 / 9.0), (0.0, 8.0 / 9.0), (x3, 5.0 / 9.0)];
        let points: Vec<(f64, f64)> = (0..segments)
            .flat_map(|s| {
                let centre = -0.5 * g.cell + (s as f64 + 0.5) * seg;
                rule.map(|(x, w)| (centre + 0.5 * seg * x, 0.5 * w / segments as f64))
            })
            .collect();
        let mut w = vec![0f32; n_delta * stride];
        let mut power = vec![0f64; n_delta];
        w.par_chunks_mut(stride)
            .zip(power.par_iter_mut())
            .enumerate()
            .for_each(|(k, (w, power))| {
                let node = -reach + k as f64 * step;
                let mut acc = vec![0f64; stride];
                for &(offset, weight) in &points {
                    let delta = node + offset;
                    *power += weight * anti.moments(delta - 0.5 * g.a, delta + 0.5 * g.a).0 / g.a;
                    for p in 0..=PHI_STEPS {
                        let phi = p as f64 / PHI_STEPS as f64;
                        for i in 0..taps {
                            acc[p * taps + i] += weight * Self::deposit(&anti, &g, delta, phi, span, i as f64);
                        }
                    }
                }
                for (out, v) in w.iter_mut().zip(&acc) {
                    *out = *v as f32;
                }
            });
        Self {
            geometry: g,
            d0: -reach,
            per_mm: 1.0 / step,
            n_delta,
            taps,
            w,
            power,
        }
    }

    /// D(δ, φ)[i] in closed form: the lenslet's u ∈ [−A/2, A/2] lands at x = φ + (u + A/2)/pix, and the
    /// hat of tap i is x − i + 1 on [i − 1, i] and i + 1 − x on [i, i + 1], linear in u on each piece, so each
    /// piece is (c₀ + c₁δ)·∫r − c₁·∫q·r over q = δ − u.
    fn deposit(anti: &Antiderivatives, g: &AxisGeometry, delta: f64, phi: f64, span: f64, i: f64) -> f64 {
        let mut value = 0.0;
        for (x_lo, x_hi, sign) in [(i - 1.0, i, 1.0), (i, i + 1.0, -1.0)] {
            let (lo, hi) = (x_lo.max(phi), x_hi.min(phi + span));
            if hi <= lo {
                continue;
            }
            let (u0, u1) = ((lo - phi) * g.pix - 0.5 * g.a, (hi - phi) * g.pix - 0.5 * g.a);
            // hat = c₀ + c₁·u on this piece.
            let c1 = sign / g.pix;
            let c0 = if sign > 0.0 {
                phi + 0.5 * g.a / g.pix - i + 1.0
            } else {
                i + 1.0 - phi - 0.5 * g.a / g.pix
            };
            let (m0, m1) = anti.moments(delta - u1, delta - u0);
            value += (c0 + c1 * delta) * m0 - c1 * m1;
        }
        value / g.a
    }

    fn bytes(&self) -> usize {
        self.w.len() * 4 + self.power.len() * 8 + std::mem::size_of::<Self>()
    }

    /// The node below δ and the fraction past it, or `None` outside the table (no light lands there).
    #[inline]
    fn locate(&self, delta: f64) -> Option<(usize, f64)> {
        let f = (delta - self.d0) * self.per_mm;
        if !(f >= 0.0 && f < (self.n_delta - 1) as f64) {
            return None;
        }
        let k = f as usize;
        Some((k, f - k as f64))
    }

    /// r_A(δ): the light of one axis through the lenslet at δ from the chief crossing, per mm.
    #[inline]
    fn power_at(&self, delta: f64) -> f64 {
        self.locate(delta)
            .map_or(0.0, |(k, t)| self.power[k] + t * (self.power[k + 1] - self.power[k]))
    }

    /// The deposit's taps at δ and φ = (node `p` + fraction `s`)/PHI_STEPS, bilinear in the table, into `w`;
    /// with `slopes`, their derivative in φ into `dw`: that of the bilinear interpolation, so that ∂T/∂W is the
    /// exact derivative of the operator as built. False outside the table (no light lands there).
    #[cfg(test)]
    fn lookup(
        &self,
        delta: f64,
        p: usize,
        s: f64,
        slopes: bool,
        w: &mut [f64; MAX_TAPS],
        dw: &mut [f64; MAX_TAPS],
    ) -> bool {
        let Some((k, t)) = self.locate(delta) else {
            return false;
        };
        self.lookup_at(k, t, p, s, slopes, w, dw);
        true
    }

    /// [`Self::lookup`] at δ node `k` and fraction `t` ([`Self::locate`]).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn lookup_at(
        &self,
        k: usize,
        t: f64,
        p: usize,
        s: f64,
        slopes: bool,
        w: &mut [f64; MAX_TAPS],
        dw: &mut [f64; MAX_TAPS],
    ) {
        let taps = self.taps;
        let stride = (PHI_STEPS + 1) * taps;
        let (lo, hi) = (k * stride + p * taps, (k + 1) * stride + p * taps);
        // φ nodes p and p + 1 at δ nodes k and k + 1.
        let (near, far) = (&self.w[lo..lo + 2 * taps], &self.w[hi..hi + 2 * taps]);
        let (u, v) = (1.0 - t, t);
        for i in 0..taps.min(MAX_TAPS) {
            let a = u * near[i] as f64 + v * far[i] as f64;
            let b = u * near[taps + i] as f64 + v * far[taps + i] as f64;
            w[i] = a + s * (b - a);
            if slopes {
                dw[i] = (b - a) * PHI_STEPS as f64;
            }
        }
    }

    /// Adds `weight` times the deposit's taps at δ node `k` and fraction `t`, φ node `p` and fraction `s` (as
    /// [`Self::lookup_at`] gives them) into `out`.
    #[inline(always)]
    fn accumulate(&self, k: usize, t: f64, p: usize, s: f64, weight: f64, out: &mut [f64]) {
        let taps = self.taps;
        let stride = (PHI_STEPS + 1) * taps;
        let (lo, hi) = (k * stride + p * taps, (k + 1) * stride + p * taps);
        let (near, far) = (&self.w[lo..lo + 2 * taps], &self.w[hi..hi + 2 * taps]);
        // Bilinear weights of the four table entries.
        let (u, v) = (weight * (1.0 - t), weight * t);
        let (c00, c01, c10, c11) = (u * (1.0 - s), u * s, v * (1.0 - s), v * s);
        for (i, o) in out.iter_mut().enumerate().take(taps) {
            *o += c00 * near[i] as f64 + c01 * near[taps + i] as f64 + c10 * far[i] as f64 + c11 * far[taps + i] as f64;
        }
    }
}

/// One axis of a cell as the deposit reads it: its points and their shifts per derivative term (`[point][term]`).
type Axis<'a> = (&'a [AxisPoint], &'a [f64]);

/// A cell's deposit along one axis: the weighted mean of its points' taps, the first at retinal pixel `base`, with
/// their derivatives per term (`[term][tap]`).
#[derive(Default)]
struct AxisSum {
    base: i64,
    len: usize,
    w: Vec<f64>,
    dw: Vec<f64>,
}

impl AxisSum {
    /// The weighted mean deposit of `points` along one axis, the lenslet's edge landing at `edge` + shift and the
    /// chief crossing at `c`; false where no light lands.
    fn fill(&mut self, table: &AxisTable, edge: f64, c: f64, (points, terms): Axis<'_>, slopes: bool) -> bool {
        let taps = table.taps;
        let n_terms = if slopes { terms.len() / points.len() } else { 0 };
        // Each point's table position, or none where no light lands; the taps' extent.
        let mut at = [(0i64, 0usize, 0usize, 0f64, 0f64, 0usize); MAX_POINTS_PER_AXIS];
        let (mut lo, mut hi, mut lit) = (i64::MAX, i64::MIN, 0usize);
        for (n, point) in points.iter().enumerate() {
            let Some((k, tk)) = table.locate(point.p - c) else {
                continue;
            };
            let t = edge + point.shift;
            let base = floor(t);
            let phi = (t - base) * PHI_STEPS as f64;
            let node = (phi as usize).min(PHI_STEPS - 1);
            let base = base as i64;
            lo = lo.min(base);
            hi = hi.max(base);
            at[lit] = (base, k, node, tk, phi - node as f64, n);
            lit += 1;
        }
        if lit == 0 {
            return false;
        }
        self.base = lo;
        self.len = (hi - lo) as usize + taps;
        self.w.clear();
        self.w.resize(self.len, 0.0);
        self.dw.clear();
        self.dw.resize(self.len * n_terms, 0.0);
        let (mut dw, mut tw) = ([0.0; MAX_TAPS], [0.0; MAX_TAPS]);
        for &(base, k, node, tk, s, n) in &at[..lit] {
            let point = &points[n];
            let from = (base - lo) as usize;
            table.accumulate(k, tk, node, s, point.weight, &mut self.w[from..from + taps]);
            if slopes {
                table.lookup_at(k, tk, node, s, true, &mut tw, &mut dw);
                for (term, shift) in terms[n * n_terms..(n + 1) * n_terms].iter().enumerate() {
                    let row = &mut self.dw[term * self.len + from..term * self.len + from + taps];
                    for (acc, v) in row.iter_mut().zip(&dw[..taps]) {
                        *acc += point.weight * shift * v;
                    }
                }
            }
        }
        true
    }
}

/// One cell's deposit along one axis in an [`AxisDeposits`]: its first tap's retinal pixel, where its taps start,
/// how many (0: no light lands), and their sum.
#[derive(Clone, Copy, Default)]
struct Entry {
    base: i64,
    start: u32,
    len: u32,
    sum: f64,
}

/// Every cell's deposit along one axis for one view index and block along it (fine cells, then coarse cells),
/// with whether each coarse cell reaches the view's core along this axis.
#[derive(Default)]
struct AxisDeposits {
    n_terms: usize,
    entries: Vec<Entry>,
    near: Vec<bool>,
    w: Vec<f64>,
    /// Per entry, `[term][tap]` from `start · n_terms`.
    dw: Vec<f64>,
}

impl AxisDeposits {
    fn push(&mut self, sum: &AxisSum) {
        let w = &sum.w[..sum.len];
        self.entries.push(Entry {
            base: sum.base,
            start: self.w.len() as u32,
            len: sum.len as u32,
            sum: w.iter().sum(),
        });
        self.w.extend_from_slice(w);
        self.dw.extend_from_slice(&sum.dw[..sum.len * self.n_terms]);
    }

    #[inline]
    fn taps(&self, e: Entry) -> &[f64] {
        &self.w[e.start as usize..(e.start + e.len) as usize]
    }

    #[inline]
    fn slopes(&self, e: Entry) -> &[f64] {
        let n = self.n_terms;
        &self.dw[e.start as usize * n..(e.start + e.len) as usize * n]
    }
}

/// The most taps a deposit may have (a lenslet wider than six retinal pixels is refused by the caller).
pub(super) const MAX_TAPS: usize = 8;

/// The process's table for `g` (tabulated on first use, shared by every person and band at that wavelength).
pub(super) fn axis_table(g: AxisGeometry, sampler: &DiffractionSampler) -> Arc<AxisTable> {
    static CACHE: OnceLock<ByteBoundedCache<AxisTable>> = OnceLock::new();
    CACHE
        .get_or_init(|| ByteBoundedCache::new(TABLE_CACHE_BYTES))
        .get_or_make(format!("{g:?}"), || AxisTable::new(g, sampler), AxisTable::bytes)
}

/// One cell of the pupil: its area inside the pupil (mm²).
#[derive(Clone, Copy, Default)]
struct Cell {
    area: f64,
}

/// One of a fine cell's points along one axis: its pupil coordinate on that axis (mm), the landing's shift along
/// that axis there (retinal pixels) and its weight.
#[derive(Clone, Copy, Default)]
struct AxisPoint {
    p: f64,
    shift: f64,
    /// The point's share of the cell's area inside the pupil.
    weight: f64,
}

/// Cells' points along each axis ([`PupilCells`]): `[cell][axis][point]`, with the landing's shift along the axis
/// per unit of each derivative term, `[cell][axis][point][term]`.
#[derive(Default)]
struct Points {
    /// Each cell's first point and its points per axis.
    cells: Vec<(usize, usize)>,
    points: Vec<AxisPoint>,
    terms: Vec<f64>,
}

impl Points {
    /// Adds a cell with centroid `p` and `strips` ((weight, coordinate) per point) along each axis: each point lies
    /// on the line through the centroid, with the landing's shift there from `shift_at`.
    fn push<F>(&mut self, p: [f64; 2], strips: &[Vec<(f64, f64)>; 2], shift_at: &F) -> f64
    where
        F: Fn([f64; 2]) -> ([f64; 2], Vec<[f64; 2]>),
    {
        let mut largest = 0f64;
        self.cells.push((self.points.len(), strips[0].len()));
        for (axis, strips) in strips.iter().enumerate() {
            for &(weight, along) in strips {
                let mut at = p;
                at[axis] = along;
                let (s, t) = shift_at(at);
                largest = largest.max(s[axis].abs());
                self.points.push(AxisPoint {
                    p: along,
                    shift: s[axis],
                    weight,
                });
                self.terms.extend(t.iter().map(|v| v[axis]));
            }
        }
        largest
    }

    /// Cell `c`'s points along `axis`, and their shifts per derivative term (`[point][term]`).
    #[inline]
    fn axis(&self, c: usize, axis: usize, n_terms: usize) -> Axis<'_> {
        let (first, n) = self.cells[c];
        let at = first + axis * n;
        (&self.points[at..at + n], &self.terms[at * n_terms..(at + n) * n_terms])
    }
}

/// A coarse cell: its area and centroid, its square's corners (mm) and its fine cells.
type CoarseCell = (Cell, [f64; 2], [f64; 2], std::ops::Range<usize>);

/// The pupil's cells, fine and coarse (each coarse cell COARSE × COARSE fine ones), each seen along each axis at
/// `per_axis` points.
///
/// A cell's points along x lie on the line through its centroid, one per strip of the cell, each weighted by its
/// strip's share of the cell's area inside the pupil and placed at that share's mean coordinate, with the landing's
/// shift along x there; the same along y. Where the wavefront's curvature is along the axes, x's landing depends
/// on P_x alone and y's on P_y alone, so the cell's deposit is the product of the two axes' weighted mean deposits,
/// which the points follow however fast the landing moves. A coarse cell's strips are its fine cells' strips four
/// by four.
struct PupilCells {
    fine: Vec<Cell>,
    fine_points: Points,
    coarse: Vec<CoarseCell>,
    coarse_points: Points,
    max_shift: f64,
}

impl PupilCells {
    /// Cells of side `h` over a pupil of radius `tracer.r_p`, each with its share of the disc (sampled where the
    /// edge crosses it), ordered coarse cell by coarse cell, with `per_axis` points along each axis.
    fn new(
        tracer: &Tracer<'_>,
        h: f64,
        coarse_per: usize,
        per_axis: usize,
        with_shift: bool,
        along_motion: f64,
    ) -> Self {
        let r_p = tracer.r_p;
        let n_coarse = ((2.0 * r_p / h).ceil() as usize).div_ceil(coarse_per);
        let origin = -0.5 * (n_coarse * coarse_per) as f64 * h;
        let n_terms = tracer.term_polys.len();
        let k = tracer.shift_per_grad;
        let shift_at = |p: [f64; 2]| {
            if !with_shift {
                return ([0.0; 2], vec![[0.0; 2]; n_terms]);
            }
            let g = tracer.poly.gradient(p[0] / r_p, p[1] / r_p);
            let t: Vec<[f64; 2]> = tracer
                .term_polys
                .iter()
                .map(|tp| {
                    let g = tp.gradient(p[0] / r_p, p[1] / r_p);
                    [k * g[0], k * g[1]]
                })
                .collect();
            ([k * g[0], k * g[1]], t)
        };
        let mut cells = Self {
            fine: Vec::new(),
            fine_points: Points::default(),
            coarse: Vec::new(),
            coarse_points: Points::default(),
            max_shift: 0.0,
        };
        let r2 = r_p * r_p;
        for cy in 0..n_coarse {
            for cx in 0..n_coarse {
                let start = cells.fine.len();
                let (mut area, mut moment) = (0.0, [0.0; 2]);
                // The coarse strips' (area, moment) along each axis.
                let mut coarse_strips = [vec![(0.0, 0.0); per_axis], vec![(0.0, 0.0); per_axis]];
                let coarse_lo = [
                    origin + (cx * coarse_per) as f64 * h,
                    origin + (cy * coarse_per) as f64 * h,
                ];
                let coarse_strip = coarse_per as f64 * h / per_axis as f64;
                for fy in 0..coarse_per {
                    for fx in 0..coarse_per {
                        let lo = [coarse_lo[0] + fx as f64 * h, coarse_lo[1] + fy as f64 * h];
                        // A cell the pupil's edge cuts is taken as `split` × `split` cells, so that the product
                        // of its marginals stays close to its joint light where the landing moves across it.
                        let split = if disc_share(lo, h, r_p, r2).is_some_and(|(a, _)| a < h * h) {
                            let mut split = 1;
                            while split < per_axis.min(EDGE_SPLIT) && along_motion / split as f64 > EDGE_MOTION {
                                split *= 2;
                            }
                            split
                        } else {
                            1
                        };
                        let side = h / split as f64;
                        for sy in 0..split {
                            for sx in 0..split {
                                let lo = [lo[0] + sx as f64 * side, lo[1] + sy as f64 * side];
                                let Some((a, p, strips)) = disc_strips(lo, side, r_p, r2, per_axis / split) else {
                                    continue;
                                };
                                area += a;
                                for n in 0..2 {
                                    moment[n] += a * p[n];
                                }
                                for axis in 0..2 {
                                    for &(w, along) in &strips[axis] {
                                        let k = ((along - coarse_lo[axis]) / coarse_strip) as usize;
                                        let acc = &mut coarse_strips[axis][k.min(per_axis - 1)];
                                        acc.0 += a * w;
                                        acc.1 += a * w * along;
                                    }
                                }
                                let largest = cells.fine_points.push(p, &strips, &shift_at);
                                cells.max_shift = cells.max_shift.max(largest);
                                cells.fine.push(Cell { area: a });
                            }
                        }
                    }
                }
                if area > 0.0 {
                    let lo = [
                        origin + (cx * coarse_per) as f64 * h,
                        origin + (cy * coarse_per) as f64 * h,
                    ];
                    let hi = [lo[0] + coarse_per as f64 * h, lo[1] + coarse_per as f64 * h];
                    let p = [moment[0] / area, moment[1] / area];
                    let strip = coarse_strip;
                    let strips = [0, 1].map(|axis| {
                        coarse_strips[axis]
                            .iter()
                            .enumerate()
                            .map(|(k, &(w, m))| {
                                if w > 0.0 {
                                    (w / area, m / w)
                                } else {
                                    (0.0, lo[axis] + (k as f64 + 0.5) * strip)
                                }
                            })
                            .collect()
                    });
                    cells.coarse_points.push(p, &strips, &shift_at);
                    let cell = Cell { area };
                    cells.coarse.push((cell, lo, hi, start..cells.fine.len()));
                }
            }
        }
        cells
    }
}

impl PupilCells {
    /// Whether the coarse cell [lo, hi] reaches a view's core (half-width `core` about its chief crossing `c`),
    /// where its fine cells are taken one by one.
    #[inline]
    fn near(&self, lo: &[f64; 2], hi: &[f64; 2], c: [f64; 2], core: f64) -> bool {
        (0..2).all(|n| hi[n] >= c[n] - core && lo[n] <= c[n] + core)
    }
}

/// The area of the square [lo, lo + h]² inside the disc of radius `r` (r² = `r2`) and its centroid: whole or
/// none where the square lies clear of the edge, else from 8 × 8 points.
fn disc_share(lo: [f64; 2], h: f64, r: f64, r2: f64) -> Option<(f64, [f64; 2])> {
    let centre = [lo[0] + 0.5 * h, lo[1] + 0.5 * h];
    let dist = centre[0].hypot(centre[1]);
    let half_diagonal = h * std::f64::consts::FRAC_1_SQRT_2;
    if dist + half_diagonal <= r {
        return Some((h * h, centre));
    }
    if dist - half_diagonal >= r {
        return None;
    }
    const N: usize = 8;
    let (mut count, mut sum) = (0usize, [0.0; 2]);
    for j in 0..N {
        for i in 0..N {
            let p = [
                lo[0] + (i as f64 + 0.5) * h / N as f64,
                lo[1] + (j as f64 + 0.5) * h / N as f64,
            ];
            if p[0] * p[0] + p[1] * p[1] <= r2 {
                count += 1;
                sum[0] += p[0];
                sum[1] += p[1];
            }
        }
    }
    (count > 0).then(|| {
        (
            h * h * count as f64 / (N * N) as f64,
            [sum[0] / count as f64, sum[1] / count as f64],
        )
    })
}

/// The square [lo, lo + h]² inside the disc of radius `r` (r² = `r2`) as [`disc_share`] gives it, with its
/// marginal along each axis in `n` strips: each strip's share of the inside area and the mean coordinate of its
/// inside part, from M × M points (M a multiple of n, at least 8) where the edge crosses the square.
#[allow(clippy::type_complexity)]
fn disc_strips(lo: [f64; 2], h: f64, r: f64, r2: f64, n: usize) -> Option<(f64, [f64; 2], [Vec<(f64, f64)>; 2])> {
    let (area, centre) = disc_share(lo, h, r, r2)?;
    let strip = h / n as f64;
    if area >= h * h {
        let even = |axis: usize| {
            (0..n)
                .map(|i| (1.0 / n as f64, lo[axis] + (i as f64 + 0.5) * strip))
                .collect()
        };
        return Some((area, centre, [even(0), even(1)]));
    }
    let m = n * 8usize.div_ceil(n);
    let per = m / n;
    let mut counts = [vec![0usize; n], vec![0usize; n]];
    let mut sums = [vec![0f64; n], vec![0f64; n]];
    let mut inside = 0usize;
    for j in 0..m {
        for i in 0..m {
            let q = [
                lo[0] + (i as f64 + 0.5) * h / m as f64,
                lo[1] + (j as f64 + 0.5) * h / m as f64,
            ];
            if q[0] * q[0] + q[1] * q[1] > r2 {
                continue;
            }
            inside += 1;
            for (axis, k) in [i, j].into_iter().enumerate() {
                counts[axis][k / per] += 1;
                sums[axis][k / per] += q[axis];
            }
        }
    }
    if inside == 0 {
        return None;
    }
    let marginal = |axis: usize| {
        (0..n)
            .map(|k| match counts[axis][k] {
                0 => (0.0, lo[axis] + (k as f64 + 0.5) * strip),
                c => (c as f64 / inside as f64, sums[axis][k] / c as f64),
            })
            .collect()
    };
    Some((area, centre, [marginal(0), marginal(1)]))
}

/// Whether a wave-optics build for an eye at the design distance from `display` with `options` makes its kernels
/// by quadrature, so that they carry no sampling noise and do not depend on the seed: a lenslet display whose
/// lenslet spans at most six retinal pixels, with the quadrature asked for (the default).
pub fn deterministic_kernels(
    display: &crate::physics::display::DisplayGeometry,
    options: &super::TransportOptions,
) -> bool {
    let pixel = super::RetinalGrid::for_display(display, options.retina_oversample).pixel_mm;
    options.wave.is_some_and(|w| w.kernel_rays > 0)
        && display.aperture == crate::physics::display::Aperture::Lenslet
        && options.sequence == super::SubRaySequence::Quadrature
        && (display.hole_diameter_mm / pixel - 1e-9).ceil() as usize + 2 <= MAX_TAPS
}

impl Tracer<'_> {
    /// The geometry of one axis of this display's lenslets at this wavelength and distance.
    fn axis_geometry(&self) -> AxisGeometry {
        let d = self.display;
        let lambda_mm = self.options.wave.expect("a wave-optics build").wavelength_nm * 1e-6;
        AxisGeometry {
            a: d.hole_diameter_mm,
            w: d.screen_pixel_pitch_mm * self.d_eye / d.gap_mm,
            b: lambda_mm * self.d_eye / d.hole_diameter_mm,
            pix: self.grid.pixel_mm,
            cell: lambda_mm * self.d_eye / d.hole_diameter_mm / CELLS_PER_B,
        }
    }

    /// Whether this build's kernels are made by quadrature ([`deterministic_kernels`]).
    pub(super) fn uses_quadrature(&self) -> bool {
        deterministic_kernels(self.display, self.options)
    }

    /// The chief crossing c of view (i, j) from the block `m` over, and the blocks whose light can reach.
    fn chief(&self, off: [f64; 2], m: [i64; 2]) -> [f64; 2] {
        let d = self.display;
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        let eye = [self.eye.x_mm, self.eye.y_mm];
        std::array::from_fn(|n| self.d_eye * (-(m[n] as f64) * d.hole_pitch_mm * aim - off[n]) / d.gap_mm - eye[n])
    }

    /// The window of blocks around the eye's: the same as the sampled kernels'.
    fn quadrature_window(&self) -> ([i64; 2], i64) {
        let d = self.display;
        let wave = self.options.wave.expect("a wave-optics build");
        let nb = wave.neighbour_blocks.max(crate::physics::observer::neighbour_blocks(
            d,
            wave.wavelength_nm,
            2.0 * self.r_p,
            self.eye,
        )) as i64;
        let per_block = d.block_shift_at_pupil_mm(self.d_eye);
        let centre = |e: f64| (-e / per_block).round() as i64;
        ([centre(self.eye.x_mm), centre(self.eye.y_mm)], nb)
    }

    /// The light that enters the pupil from every view through every block of the window (the power the
    /// kernels are normalised by, docs/design.md §2.7), in the kernels' units.
    fn quadrature_power(&self, cells: &PupilCells, table: &AxisTable) -> f64 {
        let d = self.display;
        let ([kx, ky], nb) = self.quadrature_window();
        let core = table.geometry.core();
        let views: Vec<(u32, u32)> = (0..d.views_v)
            .flat_map(|j| (0..d.views_u).map(move |i| (i, j)))
            .collect();
        views
            .par_iter()
            .map(|&(i, j)| {
                let off = self.view_offset(i, j);
                let mut power = 0.0;
                for my in ky - nb..=ky + nb {
                    for mx in kx - nb..=kx + nb {
                        let c = self.chief(off, [mx, my]);
                        let light = |points: &Points, at: usize, area: f64| {
                            let along = |axis: usize| {
                                let (points, _) = points.axis(at, axis, 0);
                                points
                                    .iter()
                                    .map(|q| q.weight * table.power_at(q.p - c[axis]))
                                    .sum::<f64>()
                            };
                            area * along(0) * along(1)
                        };
                        for (at, (cell, lo, hi, fine)) in cells.coarse.iter().enumerate() {
                            if cells.near(lo, hi, c, core) {
                                power += fine
                                    .clone()
                                    .map(|f| light(&cells.fine_points, f, cells.fine[f].area))
                                    .sum::<f64>();
                            } else {
                                power += light(&cells.coarse_points, at, cell.area);
                            }
                        }
                    }
                }
                power
            })
            .sum()
    }

    /// Every cell's deposit along `axis` for the views in column (or row) `i` from the block `m` over along it:
    /// the chief crossing, the lenslet edge's landing and the cell's points all factor per axis, so these serve
    /// every view and block across (module documentation). Fine cells are filled only inside coarse cells that
    /// reach the view's core along this axis; coarse cells always.
    #[allow(clippy::too_many_arguments)]
    fn axis_deposits(
        &self,
        axis: usize,
        i: u32,
        m: i64,
        cells: &PupilCells,
        table: &AxisTable,
        n_terms: usize,
    ) -> AxisDeposits {
        let g = table.geometry;
        let d = self.display;
        let k = self.options.retina_oversample as f64;
        let index = if axis == 0 { [i, 0] } else { [0, i] };
        let c = self.chief(self.view_offset(index[0], index[1]), [m, m])[axis];
        // The lenslet's edge lands at t = (k − 1)/2 + (−A/2 − m·p_h)/pix + s(P).
        let edge = (k - 1.0) / 2.0 + (-0.5 * g.a - m as f64 * d.hole_pitch_mm) / g.pix;
        let core = g.core();
        let slopes = n_terms > 0;
        let mut out = AxisDeposits {
            n_terms,
            entries: Vec::with_capacity(cells.fine.len() + cells.coarse.len()),
            near: Vec::with_capacity(cells.coarse.len()),
            ..Default::default()
        };
        let mut sum = AxisSum::default();
        for (_, lo, hi, fine) in &cells.coarse {
            let near = hi[axis] >= c - core && lo[axis] <= c + core;
            out.near.push(near);
            for f in fine.clone() {
                if near && sum.fill(table, edge, c, cells.fine_points.axis(f, axis, n_terms), slopes) {
                    out.push(&sum);
                } else {
                    out.entries.push(Entry::default());
                }
            }
        }
        for at in 0..cells.coarse.len() {
            if sum.fill(table, edge, c, cells.coarse_points.axis(at, axis, n_terms), slopes) {
                out.push(&sum);
            } else {
                out.entries.push(Entry::default());
            }
        }
        out
    }

    /// View (i, j)'s kernel by quadrature (module documentation) from the axes' deposits (`xs[i][block]`,
    /// `ys[j][block]`) over the window of blocks ([`Self::quadrature_window`]), unnormalised: taps keyed relative to
    /// the block's first retinal pixel, `power` the light that entered.
    fn quadrature_view(
        &self,
        (i, j): (u32, u32),
        cells: &PupilCells,
        table: &AxisTable,
        (xs, ys): (&[AxisDeposits], &[AxisDeposits]),
        ([kx, ky], nb): ([i64; 2], i64),
    ) -> ViewKernel {
        let d = self.display;
        let g = table.geometry;
        let k = self.options.retina_oversample as f64;
        let pitch = d.hole_pitch_mm;
        let n_terms = self.term_polys.len();
        // The box holding every landing: the window's blocks, the lenslet, the largest aberration shift.
        let reach = cells.max_shift + 2.0;
        let bounds = |kc: i64| {
            let lo = (k - 1.0) / 2.0 + (-0.5 * g.a - (kc + nb) as f64 * pitch) / g.pix - reach;
            let hi = (k - 1.0) / 2.0 + (0.5 * g.a - (kc - nb) as f64 * pitch) / g.pix + reach;
            (lo.floor() as i64, hi.ceil() as i64 + 1)
        };
        let mut kernel = KernelBox::new(bounds(kx), bounds(ky), n_terms);
        let (mut evaluated, mut power) = (0u64, 0f64);
        let mut dfs = vec![0.0; n_terms];
        let blocks = (2 * nb + 1) as usize;
        let n_fine = cells.fine.len();
        for by in 0..blocks {
            let y = &ys[j as usize * blocks + by];
            for bx in 0..blocks {
                let x = &xs[i as usize * blocks + bx];
                let mut deposit = |area: f64, e: usize| {
                    evaluated += 1;
                    let (ex, ey) = (x.entries[e], y.entries[e]);
                    if ex.len == 0 || ey.len == 0 {
                        return;
                    }
                    let (wx, wy) = (x.taps(ex), y.taps(ey));
                    power += area * ex.sum * ey.sum;
                    if n_terms == 0 {
                        kernel.add_outer(ex.base, ey.base, wx, wy, area);
                        return;
                    }
                    let (dx, dy) = (x.slopes(ex), y.slopes(ey));
                    let (lx, ly) = (ex.len as usize, ey.len as usize);
                    for (b, wyb) in wy.iter().enumerate() {
                        for (a, wxa) in wx.iter().enumerate() {
                            for (t, df) in dfs.iter_mut().enumerate() {
                                *df = area * (dx[t * lx + a] * wyb + wxa * dy[t * ly + b]);
                            }
                            kernel.add(ex.base + a as i64, ey.base + b as i64, area * wxa * wyb, &dfs);
                        }
                    }
                };
                for (at, (cell, _, _, fine)) in cells.coarse.iter().enumerate() {
                    if x.near[at] && y.near[at] {
                        for f in fine.clone() {
                            deposit(cells.fine[f].area, f);
                        }
                    } else {
                        deposit(cell.area, n_fine + at);
                    }
                }
            }
        }
        ViewKernel {
            taps: kernel.taps(),
            traced: evaluated,
            in_pupil: evaluated,
            power,
        }
    }

    /// The most the landing shift s(P) changes per mm of pupil (retinal pixels) over a 17 × 17 grid of the
    /// pupil, by differences over 1 % of its radius: along its own axis (∂s_x/∂P_x, ∂s_y/∂P_y), which a cell's
    /// points follow, and across (∂s_x/∂P_y, ∂s_y/∂P_x), which they do not.
    fn shift_slopes(&self) -> (f64, f64) {
        const N: usize = 17;
        let eps = 0.01;
        let k = self.shift_per_grad;
        let (mut along, mut across) = (0f64, 0f64);
        for j in 0..N {
            for i in 0..N {
                let (x, y) = (
                    2.0 * i as f64 / (N - 1) as f64 - 1.0,
                    2.0 * j as f64 / (N - 1) as f64 - 1.0,
                );
                if x * x + y * y > 1.0 {
                    continue;
                }
                let g = self.poly.gradient(x, y);
                let gx = self.poly.gradient(x + eps, y);
                let gy = self.poly.gradient(x, y + eps);
                let per = k / (eps * self.r_p);
                along = along.max(per * (gx[0] - g[0]).abs()).max(per * (gy[1] - g[1]).abs());
                across = across.max(per * (gy[0] - g[0]).abs()).max(per * (gx[1] - g[1]).abs());
            }
        }
        (along, across)
    }

    /// Every view's kernel by quadrature, normalised as the sampled kernels are (a plain image seen at its own
    /// intensity from the design position).
    pub(super) fn quadrature_kernels(&self) -> Vec<ViewKernel> {
        let d = self.display;
        let mut g = self.axis_geometry();
        // Halve the cells until the landing moves by at most MAX_SHIFT_ACROSS_CELL across one in the direction a
        // cell's points do not follow, then take points along each axis until it moves by at most
        // MAX_SHIFT_PER_CELL between neighbours; the table is averaged over a point's share of the cell.
        let (along, across) = self.shift_slopes();
        let coarse_per = COARSE;
        for _ in 0..MAX_HALVINGS {
            if across * g.cell <= MAX_SHIFT_ACROSS_CELL {
                break;
            }
            g.cell *= 0.5;
        }
        let h = g.cell;
        let mut per_axis = 1;
        while along * h / per_axis as f64 > MAX_SHIFT_PER_CELL && per_axis < MAX_POINTS_PER_AXIS {
            per_axis *= 2;
        }
        g.cell = h / per_axis as f64;
        let table = axis_table(g, self.sampler.expect("a wave-optics build"));
        let cells = PupilCells::new(self, h, coarse_per, per_axis, true, along * h);
        let views: Vec<(u32, u32)> = (0..d.views_v)
            .flat_map(|j| (0..d.views_u).map(move |i| (i, j)))
            .collect();
        // Each axis's deposits per view index and block along it, shared by every view and block across.
        let ([kx, ky], nb) = self.quadrature_window();
        let n_terms = self.term_polys.len();
        let deposits = |axis: usize, n: u32, kc: i64| -> Vec<AxisDeposits> {
            let jobs: Vec<(u32, i64)> = (0..n).flat_map(|i| (kc - nb..=kc + nb).map(move |m| (i, m))).collect();
            jobs.par_iter()
                .map(|&(i, m)| self.axis_deposits(axis, i, m, &cells, &table, n_terms))
                .collect()
        };
        let (xs, ys) = (deposits(0, d.views_u, kx), deposits(1, d.views_v, ky));
        let mut kernels: Vec<ViewKernel> = views
            .par_iter()
            .map(|&view| self.quadrature_view(view, &cells, &table, (&xs, &ys), ([kx, ky], nb)))
            .collect();
        let at_design = self.eye.x_mm == 0.0 && self.eye.y_mm == 0.0;
        let power = if at_design {
            kernels.iter().map(|k| k.power).sum()
        } else {
            let design = self.at_design_position();
            design.quadrature_power(
                &PupilCells::new(&design, h, coarse_per, per_axis, false, along * h),
                &table,
            )
        };
        self.normalise(&mut kernels, power);
        kernels
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `secure`'s lenslets at 550 nm and the design distance.
    fn secure_axis() -> AxisGeometry {
        let (a, lambda_mm, d, g, p_s) = (1.0, 550e-6, 500.0, 500.0 / (9.0 * 0.6), 1.0 / 9.0);
        AxisGeometry {
            a,
            w: p_s * d / g,
            b: lambda_mm * d / a,
            pix: 1.0,
            cell: lambda_mm * d / a,
        }
    }

    /// The tabulated deposits against what they must be whatever the quadrature: the taps of a deposit add up to
    /// the axis's light through the lenslet, r_A(δ), whose integral over δ is the whole (1, the sinc² table being
    /// normalised over its reach); hats reproduce linear functions (Σ_i i·hat(x − i) = x), so where r is
    /// symmetric about the lenslet's centre (δ = 0) the mean landing is the lenslet's centre, φ + A/(2·pix).
    #[test]
    fn the_deposits_hold_the_lenslets_light_and_land_it_at_its_centre() {
        let g = secure_axis();
        let table = AxisTable::new(g, DiffractionSampler::shared());
        assert_eq!(table.taps, 3);
        let step = 1.0 / table.per_mm;
        let whole: f64 = table.power.iter().sum::<f64>() * step;
        assert!((whole - 1.0).abs() < 1e-3, "∫ r_A = {whole}");
        let (mut w, mut dw) = ([0.0; MAX_TAPS], [0.0; MAX_TAPS]);
        for delta in [-2.3, -0.41, 0.0, 0.17, 1.9] {
            for p in [0, 7, 16, 31] {
                assert!(table.lookup(delta, p, 0.0, false, &mut w, &mut dw));
                let sum: f64 = w[..3].iter().sum();
                let power = table.power_at(delta);
                assert!(
                    (sum - power).abs() <= 1e-5 * power.max(1e-3),
                    "δ {delta}, φ node {p}: {sum} against {power}"
                );
                if delta == 0.0 {
                    let mean: f64 = w[..3].iter().enumerate().map(|(i, v)| i as f64 * v).sum::<f64>() / sum;
                    let expected = p as f64 / PHI_STEPS as f64 + 0.5 * g.a / g.pix;
                    assert!((mean - expected).abs() < 1e-4, "φ node {p}: {mean} against {expected}");
                }
            }
        }
        // Where the view's light is (its lenslet and screen pixel, |δ| ≤ 0.8 mm) r_A is about 1/(A + w)… and
        // outside it falls to the tails.
        assert!(table.power_at(0.0) > 0.5 && table.power_at(3.0) < 0.01 * table.power_at(0.0));
    }

    /// The cells' shares of the disc add up to its area and their centroids to its centre (0), for a pupil the
    /// cells do not divide.
    #[test]
    fn the_cells_tile_the_pupil() {
        for (r, h) in [(3.0f64, 0.275f64), (2.37, 0.1)] {
            let n = (2.0 * r / h).ceil() as i64 + 2;
            let (mut area, mut moment) = (0.0, [0.0; 2]);
            for j in -n..n {
                for i in -n..n {
                    if let Some((a, p)) = disc_share([i as f64 * h, j as f64 * h], h, r, r * r) {
                        area += a;
                        moment[0] += a * p[0];
                        moment[1] += a * p[1];
                    }
                }
            }
            let disc = std::f64::consts::PI * r * r;
            assert!((area - disc).abs() < 2e-3 * disc, "{area} against {disc}");
            assert!(
                moment[0].abs() < 1e-9 * disc && moment[1].abs() < 1e-9 * disc,
                "{moment:?}"
            );
        }
    }
}
