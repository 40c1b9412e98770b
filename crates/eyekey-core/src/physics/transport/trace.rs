//! The ray tracer that builds T and ∂T/∂W (paper Eqs. 9–11).

use super::rng::SplitMix64;
use crate::physics::diffraction::DiffractionSampler;
use crate::physics::display::{Aperture, DisplayGeometry};
use crate::physics::transport::{
    CsrMatrix, EyePosition, RetinalGrid, TransportError, TransportMatrix, TransportOptions, TransportStats,
};
use crate::physics::zernike::{ZernikeCoefficients, ZernikePolynomial};
use rayon::prelude::*;

/// Holes traced per parallel pass of a per-sample build (a wave-optics build checks its memory after each).
const HOLES_PER_PASS: usize = 512;

/// One sub-ray's landing point before splatting.
pub(crate) struct Landing {
    col: u32,
    /// Landing point in retinal-grid pixel units.
    f: [f64; 2],
}

/// One bilinear splat: a (landing, corner) pair keyed by (column, row).
pub(crate) struct Splat {
    key: u64,
    w: f32,
    landing: u32,
    corner: u8,
}

/// ⌊x⌋ for |x| < 2⁶³ (0 for NaN), without the library call `f64::floor` becomes on the baseline x86-64
/// target, which has no rounding instruction.
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// (sin 2πt, cos 2πt) for t in [0, 1), within 2 ulp of `f64::sin_cos`, in straight-line arithmetic the
/// compiler vectorises (the library's `sin_cos` is a call per value): t is reduced exactly to the nearest
/// quarter turn q/4, y = 2π(t − q/4) lies in [−π/4, π/4], where the Taylor series of sin to y¹⁵ and of cos to
/// y¹⁶ leave less than 10⁻¹⁶ (A&S 4.3.65–66: the first term dropped bounds the error of an alternating series),
/// and the quarter turns are exact sign and swap rules.
#[inline(always)]
pub(crate) fn sin_cos_turns(t: f64) -> (f64, f64) {
    // q in 0..=4 (t < 1); t − q/4 is exact: both are multiples of t's ulp and the difference is below 1/8.
    let q = (4.0 * t + 0.5) as i32;
    let y = std::f64::consts::TAU * (t - 0.25 * q as f64);
    let z = y * y;
    let s = y
        * (1.0
            + z * (-1.0 / 6.0
                + z * (1.0 / 120.0
                    + z * (-1.0 / 5_040.0
                        + z * (1.0 / 362_880.0
                            + z * (-1.0 / 39_916_800.0
                                + z * (1.0 / 6_227_020_800.0 + z * (-1.0 / 1_307_674_368_000.0))))))));
    let c = 1.0
        + z * (-0.5
            + z * (1.0 / 24.0
                + z * (-1.0 / 720.0
                    + z * (1.0 / 40_320.0
                        + z * (-1.0 / 3_628_800.0
                            + z * (1.0 / 479_001_600.0
                                + z * (-1.0 / 87_178_291_200.0 + z * (1.0 / 20_922_789_888_000.0))))))));
    // A quarter turn more: (sin, cos) → (cos, −sin).
    let (sin, cos) = if q & 1 == 0 { (s, c) } else { (c, s) };
    let sin = if q & 2 == 0 { sin } else { -sin };
    let cos = if (q + 1) & 2 == 0 { cos } else { -cos };
    (sin, cos)
}

/// Bilinear weight of `corner` (bit 0: +x, bit 1: +y) for a point at `f` (pixel units), and its gradient
/// with respect to f.
pub(crate) fn bilinear(f: [f64; 2], corner: u8) -> (f64, [f64; 2]) {
    let (tx, ty) = (f[0] - floor(f[0]), f[1] - floor(f[1]));
    let (wx, dwx) = if corner & 1 == 0 { (1.0 - tx, -1.0) } else { (tx, 1.0) };
    let (wy, dwy) = if corner & 2 == 0 { (1.0 - ty, -1.0) } else { (ty, 1.0) };
    (wx * wy, [dwx * wy, wx * dwy])
}

/// One hole's traced and splatted light: entries sorted by column, then row.
struct HoleOut {
    cols: Vec<u32>,
    rows: Vec<u32>,
    w: Vec<f32>,
    /// ∂w/∂W_j, `n_terms` per entry.
    dw: Vec<f32>,
    traced: u64,
    in_pupil: u64,
    off_grid: u64,
}

/// Checks a build's options and eye position; returns the eye's distance from the barrier, mm.
fn check_options(
    display: &DisplayGeometry,
    eye: EyePosition,
    options: &TransportOptions,
) -> Result<f64, TransportError> {
    if options.sub_rays == 0 || options.sub_rays > 1024 {
        return Err(TransportError::Invalid {
            field: "sub_rays",
            reason: format!("must be within 1..=1024, got {}", options.sub_rays),
        });
    }
    if options.retina_oversample == 0 || options.retina_oversample > 8 {
        return Err(TransportError::Invalid {
            field: "retina_oversample",
            reason: format!("must be within 1..=8, got {}", options.retina_oversample),
        });
    }
    if options.tracked && !(options.wave.is_some_and(|w| w.kernel_rays > 0) && eye.dz_mm == 0.0) {
        return Err(TransportError::Invalid {
            field: "tracked",
            reason: "frames re-indexed for the eye are modelled under wave optics at the design distance only".into(),
        });
    }
    let d_eye = display.viewing_distance_mm + eye.dz_mm;
    if !(d_eye.is_finite() && d_eye > 10.0) {
        return Err(TransportError::Invalid {
            field: "eye.dz_mm",
            reason: format!("the eye would be {d_eye} mm from the barrier"),
        });
    }
    Ok(d_eye)
}

/// What every hole's trace shares: the geometry, the eye and its wavefront.
pub(super) struct Tracer<'a> {
    pub(super) display: &'a DisplayGeometry,
    pub(super) eye: EyePosition,
    pub(super) options: &'a TransportOptions,
    pub(super) d_eye: f64,
    pub(super) grid: RetinalGrid,
    pub(super) r_p: f64,
    pub(super) poly: ZernikePolynomial,
    pub(super) term_polys: Vec<ZernikePolynomial>,
    /// Retinal pixels of landing shift per unit of ∂W/∂ρ (µm).
    pub(super) shift_per_grad: f64,
    /// Diffraction-angle tables, for a wave-optics build.
    pub(super) sampler: Option<&'static DiffractionSampler>,
    /// A wave-optics build's weight of one sub-ray (the same for every aperture: physical brightness).
    pub(super) wave_weight: f64,
}

/// Which block, counted from the hole's own, an eye at lateral position `eye` (mm) and distance `d_eye` from
/// the barrier sees through the hole centred at `hole` (mm): the chief ray from the eye through the hole meets
/// the screen at q = h + (h − e)·g/d_eye, and the blocks are centred at h_b·(1 + g/d) (aimed at the design eye
/// position, docs/design.md §2), so it lands in block (h(1 + g/d_eye) − e·g/d_eye) / (p_h(1 + g/d)). At the
/// design distance this is the hole's own block shifted by k = −e/(p_h(1 + g/d)·d/g), the same for every
/// hole; nearer or farther, the offset grows across the display (the view is magnified or shrunk).
pub fn block_seen(display: &DisplayGeometry, d_eye: f64, eye: [f64; 2], hole: [f64; 2]) -> [i64; 2] {
    let (g, p) = (display.gap_mm, display.hole_pitch_mm);
    let aim = 1.0 + g / display.viewing_distance_mm;
    let k = |h: f64, e: f64| ((h * (1.0 + g / d_eye) - e * g / d_eye) / (p * aim) - h / p).round() as i64;
    [k(hole[0], eye[0]), k(hole[1], eye[1])]
}

impl Tracer<'_> {
    /// Traces hole `h`'s sub-rays (S per view, jittered over the aperture and the screen pixel's square) to
    /// the pupil; returns the landings of those that enter it, their ∂f/∂W_j (flat, landing × term) and the
    /// number traced. A geometric build traces the hole's own block; a wave-optics build also the blocks
    /// around it, and adds a diffraction angle to every sub-ray.
    fn trace_hole(&self, h: usize) -> (Vec<Landing>, Vec<[f64; 2]>, u64) {
        let display = self.display;
        let (hx, hy) = ((h as u32) % display.holes_x, (h as u32) / display.holes_x);
        let mut rng = SplitMix64(self.options.seed ^ (h as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let s = self.options.sub_rays as usize;
        let views = (display.views_u * display.views_v) as usize;
        let mut landings: Vec<Landing> = Vec::with_capacity(views * s);
        let mut dfs: Vec<[f64; 2]> = Vec::with_capacity(views * s * self.term_polys.len());
        let mut traced = 0u64;
        // The blocks around the one this hole shows the eye: see `block_seen`.
        let (nb, kx, ky) = match self.options.wave {
            None => (0, 0, 0),
            Some(w) => {
                let centre = display.hole_centre_mm(hx, hy);
                let k = block_seen(display, self.d_eye, [self.eye.x_mm, self.eye.y_mm], centre);
                (w.neighbour_blocks as i64, k[0], k[1])
            }
        };
        let (y0, x0) = (hy as i64 + ky, hx as i64 + kx);
        for by in (y0 - nb).max(0)..=(y0 + nb).min(display.holes_y as i64 - 1) {
            for bx in (x0 - nb).max(0)..=(x0 + nb).min(display.holes_x as i64 - 1) {
                let block = (bx as u32, by as u32);
                traced += self.trace_block(hx, hy, block, &mut rng, &mut landings, &mut dfs);
            }
        }
        (landings, dfs, traced)
    }

    /// Traces the sub-rays from the screen pixels of `block` through aperture (hx, hy); returns how many.
    fn trace_block(
        &self,
        hx: u32,
        hy: u32,
        block: (u32, u32),
        rng: &mut SplitMix64,
        landings: &mut Vec<Landing>,
        dfs: &mut Vec<[f64; 2]>,
    ) -> u64 {
        let display = self.display;
        let centre = display.hole_centre_mm(hx, hy);
        let a = display.hole_diameter_mm;
        let mut traced = 0u64;
        for j in 0..display.views_v {
            for i in 0..display.views_u {
                let q0 = display.screen_pixel_centre_mm(block.0, block.1, i, j);
                let col = display.sample_index(block.0, block.1, i, j) as u32;
                for _ in 0..self.options.sub_rays {
                    traced += 1;
                    // The ray's slope is num/g (+ a diffraction angle); kept as a numerator so the geometric
                    // model evaluates exactly the expression it always has.
                    let (sx, sy, num, diffraction) = match display.aperture {
                        Aperture::Pinhole => {
                            // Uniform point in the hole's disc and in the screen pixel's square; slope (s − q)/g.
                            let rho = 0.5 * a * rng.next_f64().sqrt();
                            let (sin, cos) = (std::f64::consts::TAU * rng.next_f64()).sin_cos();
                            let (sx, sy) = (centre[0] + rho * cos, centre[1] + rho * sin);
                            let qx = q0[0] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            let qy = q0[1] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            (sx, sy, [sx - qx, sy - qy], [0.0; 2])
                        }
                        Aperture::Lenslet => {
                            // The lens collimates each screen point q at its focal plane: every point of the
                            // square aperture leaves with the chief ray's slope (h − q)/f.
                            let sx = centre[0] + (rng.next_f64() - 0.5) * a;
                            let sy = centre[1] + (rng.next_f64() - 0.5) * a;
                            let qx = q0[0] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            let qy = q0[1] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            (sx, sy, [centre[0] - qx, centre[1] - qy], [0.0; 2])
                        }
                    };
                    let diffraction = match (&self.sampler, self.options.wave) {
                        (Some(sampler), Some(w)) => {
                            let (u1, u2) = (rng.next_f64(), rng.next_f64());
                            match display.aperture {
                                Aperture::Pinhole => sampler.pinhole_angle(a, w.wavelength_nm, u1, u2),
                                Aperture::Lenslet => sampler.lenslet_angle(a, w.wavelength_nm, u1, u2),
                            }
                        }
                        _ => diffraction,
                    };
                    if let Some(f) = self.land(sx, sy, num, diffraction, dfs) {
                        landings.push(Landing { col, f });
                    }
                }
            }
        }
        traced
    }

    /// The landing (retinal-grid pixel units) of the ray from screen point q through barrier point s, or
    /// `None` if the iris stops it; pushes its ∂f/∂W_j onto `dfs`.
    fn land(&self, sx: f64, sy: f64, num: [f64; 2], theta: [f64; 2], dfs: &mut Vec<[f64; 2]>) -> Option<[f64; 2]> {
        let (g, gap) = (&self.grid, self.display.gap_mm);
        // The ray leaves the barrier at s with slope (u, v) = num/g + θ and meets the pupil plane at
        // P = s + d·(u, v).
        let px = sx + self.d_eye * num[0] / gap + self.d_eye * theta[0] - self.eye.x_mm;
        let py = sy + self.d_eye * num[1] / gap + self.d_eye * theta[1] - self.eye.y_mm;
        let (ux, uy) = (px / self.r_p, py / self.r_p);
        if ux * ux + uy * uy > 1.0 {
            return None;
        }
        let grad = self.poly.gradient(ux, uy);
        for tp in &self.term_polys {
            let gk = tp.gradient(ux, uy);
            dfs.push([self.shift_per_grad * gk[0], self.shift_per_grad * gk[1]]);
        }
        Some([
            (sx - g.origin_mm[0]) / g.pixel_mm + self.shift_per_grad * grad[0],
            (sy - g.origin_mm[1]) / g.pixel_mm + self.shift_per_grad * grad[1],
        ])
    }

    /// Bilinear splat: one entry per (landing, corner) inside the grid, keyed by (column, row), each landing
    /// weighted `weight`; returns the entries sorted by key and how many landings fell entirely off the grid.
    fn splat(&self, landings: &[Landing], weight: f64) -> (Vec<Splat>, u64) {
        let grid = &self.grid;
        let mut entries: Vec<Splat> = Vec::with_capacity(landings.len() * 4);
        let mut off_grid = 0u64;
        for (li, l) in landings.iter().enumerate() {
            let (x0, y0) = (l.f[0].floor(), l.f[1].floor());
            let mut any = false;
            for corner in 0..4u8 {
                let (gx, gy) = (x0 as i64 + (corner & 1) as i64, y0 as i64 + (corner >> 1) as i64);
                if gx < 0 || gy < 0 || gx >= grid.width as i64 || gy >= grid.height as i64 {
                    continue;
                }
                any = true;
                let row = (gy as u32) * grid.width + gx as u32;
                let (w, _) = bilinear(l.f, corner);
                entries.push(Splat {
                    key: (u64::from(l.col) << 32) | u64::from(row),
                    w: (weight * w) as f32,
                    landing: li as u32,
                    corner,
                });
            }
            if !any {
                off_grid += 1;
            }
        }
        entries.sort_unstable_by_key(|e| e.key);
        (entries, off_grid)
    }

    /// One hole's entries of T and ∂T/∂W_j. Its light is normalised by the sub-rays that entered the pupil
    /// and spread over k² retinal pixels per hole pitch, so a plain image keeps its intensity.
    fn hole(&self, h: usize) -> HoleOut {
        let (landings, dfs, traced) = self.trace_hole(h);
        let in_pupil = landings.len() as u64;
        let k2 = (self.options.retina_oversample * self.options.retina_oversample) as f64;
        let weight = if self.options.wave.is_some() {
            self.wave_weight
        } else if in_pupil > 0 {
            k2 / in_pupil as f64
        } else {
            0.0
        };
        let (entries, off_grid) = self.splat(&landings, weight);
        let n_terms = self.term_polys.len();
        let mut out = HoleOut {
            cols: Vec::with_capacity(entries.len()),
            rows: Vec::with_capacity(entries.len()),
            w: Vec::with_capacity(entries.len()),
            dw: Vec::with_capacity(entries.len() * n_terms),
            traced,
            in_pupil,
            off_grid,
        };
        let mut last_key = u64::MAX;
        for e in entries {
            if e.key != last_key {
                out.cols.push((e.key >> 32) as u32);
                out.rows.push(e.key as u32);
                out.w.push(0.0);
                out.dw.extend(std::iter::repeat_n(0.0, n_terms));
                last_key = e.key;
            }
            *out.w.last_mut().expect("an entry was pushed") += e.w;
            if n_terms > 0 {
                // ∂(wx·wy)/∂W_j = ∂wx/∂fx·wy·∂fx/∂W_j + wx·∂wy/∂fy·∂fy/∂W_j.
                let l = &landings[e.landing as usize];
                let (_, dwdf) = bilinear(l.f, e.corner);
                let base = out.dw.len() - n_terms;
                let df = &dfs[e.landing as usize * n_terms..(e.landing as usize + 1) * n_terms];
                for (k, d) in df.iter().enumerate() {
                    out.dw[base + k] += (weight * (dwdf[0] * d[0] + dwdf[1] * d[1])) as f32;
                }
            }
        }
        out
    }
}

impl Tracer<'_> {
    /// A wave-optics build's weight per sub-ray: k² over the mean number of sub-rays per aperture that enter
    /// this pupil from the design position, so that a plain image is seen at its own intensity there (the
    /// eye adapted to the display), and brightness at other apertures and eye positions is the light that
    /// enters the pupil.
    fn physical_weight(&self) -> f64 {
        if self.options.wave.is_none() {
            return 0.0;
        }
        let design = Tracer {
            eye: EyePosition::default(),
            d_eye: self.display.viewing_distance_mm,
            shift_per_grad: self.shift_per_grad / self.d_eye * self.display.viewing_distance_mm,
            sampler: self.sampler,
            term_polys: Vec::new(),
            poly: self.poly.clone(),
            ..*self
        };
        // The mean over a 5×5 grid of apertures between a sixth and five sixths of the barrier.
        let (hx, hy) = (self.display.holes_x as usize, self.display.holes_y as usize);
        let picks: Vec<usize> = (0..25)
            .map(|k| {
                let (i, j) = (k % 5, k / 5);
                let x = (hx * (1 + i) / 6).min(hx - 1);
                let y = (hy * (1 + j) / 6).min(hy - 1);
                y * hx + x
            })
            .collect();
        let total: usize = picks.par_iter().map(|&h| design.trace_hole(h).0.len()).sum();
        let n = total as f64 / picks.len() as f64;
        let k2 = (self.options.retina_oversample * self.options.retina_oversample) as f64;
        if n > 0.0 {
            k2 / n
        } else {
            0.0
        }
    }
}

/// Assembles Tᵀ (rows = light-field samples) and its derivative values from the per-hole lists.
fn assemble(
    holes: &[HoleOut],
    n_cols: usize,
    n_rows: usize,
    n_terms: usize,
) -> Result<(CsrMatrix, Vec<Vec<f32>>, TransportStats), TransportError> {
    let nnz: usize = holes.iter().map(|h| h.cols.len()).sum();
    if nnz >= u32::MAX as usize {
        return Err(TransportError::TooLarge(nnz));
    }
    let mut counts = vec![0u32; n_cols + 1];
    for h in holes {
        for &c in &h.cols {
            counts[c as usize + 1] += 1;
        }
    }
    for i in 0..n_cols {
        counts[i + 1] += counts[i];
    }
    let mut t_indices = vec![0u32; nnz];
    let mut t_values = vec![0f32; nnz];
    let mut t_dvalues: Vec<Vec<f32>> = vec![vec![0f32; nnz]; n_terms];
    let mut next = counts.clone();
    let mut stats = TransportStats::default();
    for h in holes {
        stats.sub_rays_traced += h.traced;
        stats.sub_rays_in_pupil += h.in_pupil;
        stats.sub_rays_off_grid += h.off_grid;
        stats.holes_seen += u64::from(h.in_pupil > 0);
        for e in 0..h.cols.len() {
            let c = h.cols[e] as usize;
            let dst = next[c] as usize;
            next[c] += 1;
            t_indices[dst] = h.rows[e];
            t_values[dst] = h.w[e];
            for (k, dv) in t_dvalues.iter_mut().enumerate() {
                dv[dst] = h.dw[e * n_terms + k];
            }
        }
    }
    let adjoint = CsrMatrix {
        n_rows: n_cols,
        n_cols: n_rows,
        indptr: counts,
        indices: t_indices,
        values: t_values,
    };
    Ok((adjoint, t_dvalues, stats))
}

impl TransportMatrix {
    /// Builds T for one observer (wavefront `wavefront`, at `eye`) looking at `display`.
    ///
    /// `wavefront` must already be at the viewing pupil (see `VisionProfile::effective_wavefront`).
    pub fn build(
        display: &DisplayGeometry,
        wavefront: &ZernikeCoefficients,
        eye: EyePosition,
        options: &TransportOptions,
    ) -> Result<Self, TransportError> {
        let d_eye = check_options(display, eye, options)?;
        let grid = RetinalGrid::for_display(display, options.retina_oversample);
        let r_p = wavefront.pupil_radius_mm();
        let tracer = Tracer {
            display,
            eye,
            options,
            d_eye,
            grid,
            r_p,
            poly: wavefront.polynomial(),
            term_polys: options
                .derivative_terms
                .iter()
                .map(|&j| ZernikePolynomial::single_term(j))
                .collect(),
            // Eq. 9 in display-plane units: landing = s + d·∇W, with ∇W in mrad = (1/r_p)·∂W/∂ρ (µm/mm).
            shift_per_grad: d_eye * 1e-3 / grid.pixel_mm / r_p,
            sampler: options.wave.map(|_| DiffractionSampler::shared()),
            wave_weight: 0.0,
        };
        if let Some(w) = options.wave.filter(|w| w.kernel_rays > 0 && eye.dz_mm == 0.0) {
            return Ok(Self::build_shift_invariant(&tracer, w.kernel_rays));
        }
        let tracer = Tracer {
            wave_weight: tracer.physical_weight(),
            ..tracer
        };
        // Trace and splat hole by hole in parallel; each hole's entries are merged per column. A wave-optics
        // build counts what it holds as it goes and stops at the budget, before T and Tᵀ are assembled.
        let n_holes = (display.holes_x * display.holes_y) as usize;
        let n_terms = tracer.term_polys.len();
        let mut holes: Vec<HoleOut> = Vec::with_capacity(n_holes);
        let mut bytes = 0usize;
        for start in (0..n_holes).step_by(HOLES_PER_PASS) {
            let end = (start + HOLES_PER_PASS).min(n_holes);
            let pass: Vec<HoleOut> = (start..end).into_par_iter().map(|h| tracer.hole(h)).collect();
            bytes += pass.iter().map(|h| h.cols.len()).sum::<usize>() * 8 * 2 * (1 + n_terms);
            if let Some(w) = options.wave {
                // The pass's share of the whole, extrapolated: refuse as soon as the total would exceed it.
                let projected = bytes / end * n_holes;
                if projected > options.max_traced_wave_bytes {
                    return Err(TransportError::OverBudget {
                        mib: projected >> 20,
                        limit_mib: options.max_traced_wave_bytes >> 20,
                        apertures: (2 * w.neighbour_blocks as usize + 1).pow(2),
                    });
                }
            }
            holes.extend(pass);
        }
        let (adjoint, t_dvalues, stats) = assemble(&holes, display.n_samples_per_band(), grid.len(), n_terms)?;
        Ok(finish(
            grid,
            adjoint,
            t_dvalues,
            options.derivative_terms.clone(),
            stats,
        ))
    }
}

/// The operator from Tᵀ and its derivative values: T and ∂T/∂W_j on T's pattern come from one transpose.
pub(super) fn finish(
    grid: RetinalGrid,
    adjoint: CsrMatrix,
    t_dvalues: Vec<Vec<f32>>,
    derivative_terms: Vec<usize>,
    stats: TransportStats,
) -> TransportMatrix {
    let (forward, map) = adjoint.transpose_with_map();
    let derivative_forward = t_dvalues
        .iter()
        .map(|dv| map.iter().map(|&m| dv[m as usize]).collect())
        .collect();
    TransportMatrix {
        grid,
        derivative_terms,
        stats,
        repr: super::Repr::Sparse(super::Sparse {
            forward,
            adjoint,
            derivative_forward,
            derivative_adjoint: t_dvalues,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_turns_is_the_library_s_within_two_ulp() {
        let ulp = |v: f64| f64::EPSILON * v.abs().max(f64::MIN_POSITIVE);
        // Every quarter turn's edges, the exact quarter turns, and a dense sweep.
        let mut ts: Vec<f64> = (0..100_000).map(|k| k as f64 / 100_000.0).collect();
        for q in 0..4 {
            let edge = 0.125 + 0.25 * q as f64;
            ts.extend([
                edge,
                f64::from_bits(edge.to_bits() - 1),
                f64::from_bits(edge.to_bits() + 1),
            ]);
        }
        ts.push(f64::from_bits(1f64.to_bits() - 1));
        for t in ts {
            let (s, c) = sin_cos_turns(t);
            let (s0, c0) = (std::f64::consts::TAU * t).sin_cos();
            // The library's argument 2πt is itself rounded: one ulp of 2πt moves sin and cos by that much.
            let arg = f64::EPSILON * std::f64::consts::TAU * t;
            assert!(
                (s - s0).abs() <= 2.0 * ulp(s0) + arg,
                "sin at t = {t}: {s} against {s0}"
            );
            assert!(
                (c - c0).abs() <= 2.0 * ulp(c0) + arg,
                "cos at t = {t}: {c} against {c0}"
            );
        }
        // Exact at the quarter turns.
        assert_eq!(sin_cos_turns(0.0), (0.0, 1.0));
        assert_eq!(sin_cos_turns(0.25), (1.0, -0.0));
        assert_eq!(sin_cos_turns(0.5), (-0.0, -1.0));
        assert_eq!(sin_cos_turns(0.75), (-1.0, 0.0));
    }
}
