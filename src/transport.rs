//! Light transport from the display's light field to one observer's retinal image (paper Eqs. 9–11, 13).
//!
//! The paper's T is 0/1 per ray (Eq. 10). eyekey makes it physical (DESIGN §2): for every light-field sample
//! (hole x, y; view i, j) it traces S sub-rays jittered over the hole aperture and over the screen pixel (the
//! view's angular bin), drops those that miss the pupil, moves the rest by the wavefront error (Eq. 9,
//! landing = s + d·∇W(P)), and splats each landing point bilinearly onto a retinal grid expressed in
//! display-plane coordinates. Each hole's light is normalised by the number of its sub-rays that enter the
//! pupil, so a perfect eye sees a plain 2D image (all views of a hole equal) at its own intensity.
//!
//! T is stored twice, as CSR (rows = retinal pixels, for the forward product) and as its transpose (rows =
//! light-field samples, for the adjoint), with f32 values and u32 indices. Both products are hand-written
//! rayon kernels that apply all N bands and the spectral coupling (Eq. 13: S_a = Σ_n c_na T L_n) in one pass;
//! no sparse crate offers fused multi-band kernels with this layout.
//!
//! Light-field layout everywhere: band-interleaved, `l[p * n_bands + n]` for sample p (frame order, see
//! [`DisplayGeometry::sample_index`]) and band n. Retinal images: `y[r * 3 + a]`, a = L, M, S.

use rayon::prelude::*;

use crate::display::DisplayGeometry;
use crate::optics::zernike::{ZernikeCoefficients, ZernikePolynomial};

/// Errors building a transport operator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TransportError {
    /// An option is out of range.
    #[error("{field}: {reason}")]
    Invalid {
        /// The option's name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The operator would exceed the u32 index range.
    #[error("the transport operator has {0} entries, more than u32 indices allow")]
    TooLarge(usize),
}

/// The grid on which retinal images are sampled, in display-plane coordinates (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetinalGrid {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// Pixel pitch, mm (display plane).
    pub pixel_mm: f64,
    /// Centre of pixel (0, 0), mm.
    pub origin_mm: [f64; 2],
}

impl RetinalGrid {
    /// A grid covering the barrier with `oversample` pixels per hole pitch; with 1, pixel centres are the
    /// hole centres.
    pub fn for_display(display: &DisplayGeometry, oversample: u32) -> Self {
        let k = oversample.max(1);
        let pixel_mm = display.hole_pitch_mm / k as f64;
        let width = display.holes_x * k;
        let height = display.holes_y * k;
        Self {
            width,
            height,
            pixel_mm,
            origin_mm: [
                -(width as f64 - 1.0) / 2.0 * pixel_mm,
                -(height as f64 - 1.0) / 2.0 * pixel_mm,
            ],
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        (self.width * self.height) as usize
    }

    /// True for an empty grid.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Where the viewer's pupil centre is, relative to the barrier's centre.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct EyePosition {
    /// Lateral offset, mm.
    pub x_mm: f64,
    /// Vertical offset, mm.
    pub y_mm: f64,
    /// Change of viewing distance from the display's design distance, mm (positive = farther).
    pub dz_mm: f64,
}

/// Options of a transport build.
#[derive(Clone, Debug, PartialEq)]
pub struct TransportOptions {
    /// Sub-rays per light-field sample (S).
    pub sub_rays: u32,
    /// Seed of the sub-ray jitter.
    pub seed: u64,
    /// Retinal pixels per hole pitch.
    pub retina_oversample: u32,
    /// OSA indices j whose ∂T/∂W_j is built alongside T (empty: none).
    pub derivative_terms: Vec<usize>,
}

impl Default for TransportOptions {
    fn default() -> Self {
        Self {
            sub_rays: 16,
            seed: 7,
            retina_oversample: 1,
            derivative_terms: Vec::new(),
        }
    }
}

/// A sparse matrix in compressed-row form with f32 values and u32 indices.
#[derive(Clone, Debug, PartialEq)]
pub struct CsrMatrix {
    /// Rows.
    pub n_rows: usize,
    /// Columns.
    pub n_cols: usize,
    /// Row start offsets (n_rows + 1).
    pub indptr: Vec<u32>,
    /// Column index per entry.
    pub indices: Vec<u32>,
    /// Value per entry.
    pub values: Vec<f32>,
}

impl CsrMatrix {
    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.indices.len()
    }

    /// The transpose and, for each of its entries, the position of the same entry in `self`.
    fn transpose_with_map(&self) -> (CsrMatrix, Vec<u32>) {
        let nnz = self.nnz();
        let mut counts = vec![0u32; self.n_cols + 1];
        for &c in &self.indices {
            counts[c as usize + 1] += 1;
        }
        for i in 0..self.n_cols {
            counts[i + 1] += counts[i];
        }
        let indptr = counts.clone();
        let mut next = counts;
        let mut indices = vec![0u32; nnz];
        let mut values = vec![0f32; nnz];
        let mut map = vec![0u32; nnz];
        for r in 0..self.n_rows {
            for e in self.indptr[r] as usize..self.indptr[r + 1] as usize {
                let c = self.indices[e] as usize;
                let dst = next[c] as usize;
                next[c] += 1;
                indices[dst] = r as u32;
                values[dst] = self.values[e];
                map[dst] = e as u32;
            }
        }
        (
            CsrMatrix {
                n_rows: self.n_cols,
                n_cols: self.n_rows,
                indptr,
                indices,
                values,
            },
            map,
        )
    }
}

/// Rows per rayon task in the sparse kernels: about eight tasks per thread (enough to balance rows of
/// uneven length), but never fewer than 64 rows (scheduling must stay cheap).
fn rows_per_task(n_rows: usize) -> usize {
    (n_rows / (8 * rayon::current_num_threads().max(1))).max(64)
}

/// out[r·3 + a] = Σ_n c[n][a] Σ_e v_e · x[col_e · N + n] (forward, Eq. 13), or with `transpose_mix`
/// out[r·N + n] = Σ_a c[n][a] Σ_e v_e · y[col_e · 3 + a] (adjoint): the sparse product fused with the spectral
/// coupling. Dispatches to a version specialised on the input width for the common 3- and 4-band cases.
#[allow(clippy::too_many_arguments)]
fn spmv_fused(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    x: &[f32],
    n_in: usize,
    mix: &[[f32; 3]],
    transpose_mix: bool,
    out: &mut [f32],
    n_out: usize,
) {
    debug_assert!(n_in <= 16 && n_out <= 16);
    match n_in {
        3 => spmv_fixed::<3>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
        4 => spmv_fixed::<4>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
        _ => spmv_fixed::<16>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
    }
}

/// The kernel for an input width of at most `NI` (exactly `NI` when NI < 16; `x.len() / n_cols` otherwise).
#[allow(clippy::too_many_arguments)]
fn spmv_fixed<const NI: usize>(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    x: &[f32],
    mix: &[[f32; 3]],
    transpose_mix: bool,
    out: &mut [f32],
    n_out: usize,
) {
    let n_in = if NI < 16 {
        NI
    } else if transpose_mix {
        3
    } else {
        mix.len()
    };
    let rows_per_chunk = rows_per_task(out.len() / n_out.max(1));
    out.par_chunks_mut(rows_per_chunk * n_out)
        .enumerate()
        .for_each(|(chunk, out_rows)| {
            let first = chunk * rows_per_chunk;
            for (k, o) in out_rows.chunks_exact_mut(n_out).enumerate() {
                let r = first + k;
                let mut acc = [0f32; NI];
                let (a, b) = (indptr[r] as usize, indptr[r + 1] as usize);
                // Two independent accumulators over alternating entries hide the FMA latency.
                let mut acc2 = [0f32; NI];
                let (idx, val) = (&indices[a..b], &values[a..b]);
                let pairs = idx.len() / 2;
                for p in 0..pairs {
                    let (i0, i1) = (idx[2 * p] as usize * n_in, idx[2 * p + 1] as usize * n_in);
                    let (v0, v1) = (val[2 * p], val[2 * p + 1]);
                    let (x0, x1) = (&x[i0..i0 + n_in], &x[i1..i1 + n_in]);
                    for ((s0, s1), (a0, a1)) in acc.iter_mut().zip(acc2.iter_mut()).zip(x0.iter().zip(x1)) {
                        *s0 += v0 * a0;
                        *s1 += v1 * a1;
                    }
                }
                if idx.len() % 2 == 1 {
                    let i0 = idx[idx.len() - 1] as usize * n_in;
                    let v0 = val[val.len() - 1];
                    for (s0, a0) in acc.iter_mut().zip(&x[i0..i0 + n_in]) {
                        *s0 += v0 * a0;
                    }
                }
                for (s0, s1) in acc.iter_mut().zip(acc2) {
                    *s0 += s1;
                }
                if transpose_mix {
                    // Adjoint: out_n = Σ_a c[n][a] acc_a.
                    for (slot, m) in o.iter_mut().zip(mix) {
                        *slot = m[0] * acc[0] + m[1] * acc[1] + m[2] * acc[2];
                    }
                } else {
                    // Forward: out_a = Σ_n c[n][a] acc_n.
                    for (a, slot) in o.iter_mut().enumerate() {
                        *slot = mix.iter().zip(&acc).map(|(m, v)| m[a] * v).sum();
                    }
                }
            }
        });
}

/// One observer's light-transport operator T (Eqs. 10, 11, 13) and, optionally, ∂T/∂W_j.
#[derive(Clone, Debug)]
pub struct TransportMatrix {
    /// The retinal grid (rows of T).
    pub grid: RetinalGrid,
    /// T: retinal pixels × light-field samples.
    pub forward: CsrMatrix,
    /// Tᵀ: light-field samples × retinal pixels.
    pub adjoint: CsrMatrix,
    /// OSA indices of the stored derivatives.
    pub derivative_terms: Vec<usize>,
    /// ∂T/∂W_j values on the pattern of `forward`, one vector per term.
    derivative_forward: Vec<Vec<f32>>,
    /// The same values on the pattern of `adjoint`.
    derivative_adjoint: Vec<Vec<f32>>,
    /// Statistics of the build.
    pub stats: TransportStats,
}

/// What a transport build traced.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TransportStats {
    /// Sub-rays traced.
    pub sub_rays_traced: u64,
    /// Sub-rays that entered the pupil.
    pub sub_rays_in_pupil: u64,
    /// Holes that sent at least one sub-ray into the pupil.
    pub holes_seen: u64,
    /// Sub-rays that landed outside the retinal grid (lost at the image's border).
    pub sub_rays_off_grid: u64,
}

/// One sub-ray's landing point before splatting.
struct Landing {
    col: u32,
    /// Landing point in retinal-grid pixel units.
    f: [f64; 2],
}

/// One bilinear splat: a (landing, corner) pair keyed by (column, row).
struct Splat {
    key: u64,
    w: f32,
    landing: u32,
    corner: u8,
}

/// Bilinear weight of `corner` (bit 0: +x, bit 1: +y) for a point at `f` (pixel units), and its gradient
/// with respect to f.
fn bilinear(f: [f64; 2], corner: u8) -> (f64, [f64; 2]) {
    let (tx, ty) = (f[0] - f[0].floor(), f[1] - f[1].floor());
    let (wx, dwx) = if corner & 1 == 0 { (1.0 - tx, -1.0) } else { (tx, 1.0) };
    let (wy, dwy) = if corner & 2 == 0 { (1.0 - ty, -1.0) } else { (ty, 1.0) };
    (wx * wy, [dwx * wy, wx * dwy])
}

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, fast, seedable generator for the sub-ray jitter.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
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
        let d_eye = display.viewing_distance_mm + eye.dz_mm;
        if !(d_eye.is_finite() && d_eye > 10.0) {
            return Err(TransportError::Invalid {
                field: "eye.dz_mm",
                reason: format!("the eye would be {d_eye} mm from the barrier"),
            });
        }
        let grid = RetinalGrid::for_display(display, options.retina_oversample);
        let r_p = wavefront.pupil_radius_mm();
        let poly = wavefront.polynomial();
        let term_polys: Vec<ZernikePolynomial> = options
            .derivative_terms
            .iter()
            .map(|&j| ZernikePolynomial::single_term(j))
            .collect();
        // Eq. 9 in display-plane units: landing = s + d·∇W, with ∇W in mrad = (1/r_p)·∂W/∂ρ (µm/mm).
        let shift_per_grad = d_eye * 1e-3 / grid.pixel_mm / r_p;
        let n_holes = (display.holes_x * display.holes_y) as usize;
        let views = (display.views_u * display.views_v) as usize;
        let s = options.sub_rays as usize;

        // Trace and splat hole by hole in parallel; each hole's entries are merged per column.
        struct HoleOut {
            /// (column, row, weight, dweights...) sorted by column then row.
            cols: Vec<u32>,
            rows: Vec<u32>,
            w: Vec<f32>,
            dw: Vec<f32>,
            traced: u64,
            in_pupil: u64,
            off_grid: u64,
        }
        let n_terms = term_polys.len();
        let holes: Vec<HoleOut> = (0..n_holes)
            .into_par_iter()
            .map(|h| {
                let (hx, hy) = ((h as u32) % display.holes_x, (h as u32) / display.holes_x);
                let centre = display.hole_centre_mm(hx, hy);
                let mut rng = SplitMix64(options.seed ^ (h as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                let mut landings: Vec<Landing> = Vec::with_capacity(views * s);
                // ∂f/∂W_j per landing, flat: landing index × n_terms.
                let mut dfs: Vec<[f64; 2]> = Vec::with_capacity(views * s * n_terms);
                let mut traced = 0u64;
                for j in 0..display.views_v {
                    for i in 0..display.views_u {
                        let q0 = display.screen_pixel_centre_mm(hx, hy, i, j);
                        let col = display.sample_index(hx, hy, i, j) as u32;
                        for _ in 0..s {
                            traced += 1;
                            // Uniform point in the hole's disc and in the screen pixel's square.
                            let rho = 0.5 * display.hole_diameter_mm * rng.next_f64().sqrt();
                            let (sin, cos) = (std::f64::consts::TAU * rng.next_f64()).sin_cos();
                            let sx = centre[0] + rho * cos;
                            let sy = centre[1] + rho * sin;
                            let qx = q0[0] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            let qy = q0[1] + (rng.next_f64() - 0.5) * display.screen_pixel_pitch_mm;
                            // Slope (u, v) = (s − q)/g; the ray meets the pupil plane at P = s + d·(u, v).
                            let px = sx + d_eye * (sx - qx) / display.gap_mm - eye.x_mm;
                            let py = sy + d_eye * (sy - qy) / display.gap_mm - eye.y_mm;
                            let (ux, uy) = (px / r_p, py / r_p);
                            if ux * ux + uy * uy > 1.0 {
                                continue; // stopped by the iris
                            }
                            let g = poly.gradient(ux, uy);
                            let f = [
                                (sx - grid.origin_mm[0]) / grid.pixel_mm + shift_per_grad * g[0],
                                (sy - grid.origin_mm[1]) / grid.pixel_mm + shift_per_grad * g[1],
                            ];
                            for tp in &term_polys {
                                let gk = tp.gradient(ux, uy);
                                dfs.push([shift_per_grad * gk[0], shift_per_grad * gk[1]]);
                            }
                            landings.push(Landing { col, f });
                        }
                    }
                }
                let in_pupil = landings.len() as u64;
                // Each hole's light, spread over k² retinal pixels per hole pitch, keeps its intensity.
                let k2 = (options.retina_oversample * options.retina_oversample) as f64;
                let weight = if in_pupil > 0 { k2 / in_pupil as f64 } else { 0.0 };
                // Bilinear splat: one entry per (landing, corner), keyed by (column, row).
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
            })
            .collect();

        // Assemble Tᵀ (rows = light-field samples) from the per-hole lists.
        let n_cols = display.n_samples_per_band();
        let nnz: usize = holes.iter().map(|h| h.cols.len()).sum();
        if nnz >= u32::MAX as usize {
            return Err(TransportError::TooLarge(nnz));
        }
        let mut counts = vec![0u32; n_cols + 1];
        for h in &holes {
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
        for h in &holes {
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
            n_cols: grid.len(),
            indptr: counts,
            indices: t_indices,
            values: t_values,
        };
        let (forward, map) = adjoint.transpose_with_map();
        let derivative_forward = t_dvalues
            .iter()
            .map(|dv| map.iter().map(|&m| dv[m as usize]).collect())
            .collect();
        Ok(Self {
            grid,
            forward,
            adjoint,
            derivative_terms: options.derivative_terms.clone(),
            derivative_forward,
            derivative_adjoint: t_dvalues,
            stats,
        })
    }

    /// Light-field samples per band (columns of T).
    pub fn n_samples(&self) -> usize {
        self.forward.n_cols
    }

    /// Retinal pixels (rows of T).
    pub fn n_pixels(&self) -> usize {
        self.forward.n_rows
    }

    /// Stored entries of T.
    pub fn nnz(&self) -> usize {
        self.forward.nnz()
    }

    /// Bytes held by the operator.
    pub fn memory_bytes(&self) -> usize {
        let m = |c: &CsrMatrix| c.indptr.len() * 4 + c.indices.len() * 4 + c.values.len() * 4;
        m(&self.forward)
            + m(&self.adjoint)
            + 4 * self
                .derivative_forward
                .iter()
                .chain(&self.derivative_adjoint)
                .map(Vec::len)
                .sum::<usize>()
    }

    /// S = (C ⊗ T)·L (Eq. 13): `l[p·N + n]` → `out[r·3 + a]`. `coupling[n][a]` = c_na.
    pub fn forward_lms(&self, l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.forward_with(&self.forward.values, l, coupling, out);
    }

    /// Lᵀ-side adjoint: `y[r·3 + a]` → `out[p·N + n]` = Σ_a c_na (Tᵀ y_a)_p.
    pub fn adjoint_lms(&self, y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.adjoint_with(&self.adjoint.values, y, coupling, out);
    }

    /// (C ⊗ ∂T/∂W_j)·L for the k-th stored derivative term.
    pub fn derivative_forward_lms(&self, k: usize, l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.forward_with(&self.derivative_forward[k], l, coupling, out);
    }

    /// Adjoint of [`Self::derivative_forward_lms`].
    pub fn derivative_adjoint_lms(&self, k: usize, y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.adjoint_with(&self.derivative_adjoint[k], y, coupling, out);
    }

    fn forward_with(&self, values: &[f32], l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        let n = coupling.len();
        assert_eq!(l.len(), self.n_samples() * n, "light field length");
        assert_eq!(out.len(), self.n_pixels() * 3, "retinal image length");
        let m = &self.forward;
        spmv_fused(&m.indptr, &m.indices, values, l, n, coupling, false, out, 3);
    }

    fn adjoint_with(&self, values: &[f32], y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        let n = coupling.len();
        assert_eq!(y.len(), self.n_pixels() * 3, "retinal image length");
        assert_eq!(out.len(), self.n_samples() * n, "light field length");
        let m = &self.adjoint;
        spmv_fused(&m.indptr, &m.indices, values, y, 3, coupling, true, out, n);
    }
}

/// A process-wide cache of transport operators, keyed by everything that determines them (display geometry,
/// wavefront, eye position, options), bounded in memory; least recently used entries are evicted first.
pub struct TransportCache {
    inner: std::sync::Mutex<CacheInner>,
}

struct CacheInner {
    capacity_bytes: usize,
    used_bytes: usize,
    tick: u64,
    entries: std::collections::HashMap<String, (std::sync::Arc<TransportMatrix>, u64)>,
    hits: u64,
    misses: u64,
}

impl TransportCache {
    /// The process-wide cache (512 MiB unless [`Self::set_capacity_bytes`] says otherwise).
    pub fn global() -> &'static TransportCache {
        static CACHE: std::sync::OnceLock<TransportCache> = std::sync::OnceLock::new();
        CACHE.get_or_init(|| TransportCache::new(512 << 20))
    }

    /// An empty cache holding at most `capacity_bytes` of operators.
    pub fn new(capacity_bytes: usize) -> Self {
        Self {
            inner: std::sync::Mutex::new(CacheInner {
                capacity_bytes,
                used_bytes: 0,
                tick: 0,
                entries: Default::default(),
                hits: 0,
                misses: 0,
            }),
        }
    }

    /// Changes the memory bound (0 disables caching), evicting as needed.
    pub fn set_capacity_bytes(&self, capacity_bytes: usize) {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        g.capacity_bytes = capacity_bytes;
        Self::evict(&mut g, 0);
    }

    /// (hits, misses, bytes held).
    pub fn stats(&self) -> (u64, u64, usize) {
        let g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        (g.hits, g.misses, g.used_bytes)
    }

    fn evict(g: &mut CacheInner, incoming: usize) {
        while g.used_bytes + incoming > g.capacity_bytes && !g.entries.is_empty() {
            let oldest = g.entries.iter().min_by_key(|(_, (_, t))| *t).map(|(k, _)| k.clone());
            if let Some(k) = oldest {
                if let Some((m, _)) = g.entries.remove(&k) {
                    g.used_bytes -= m.memory_bytes();
                }
            }
        }
    }

    /// The operator for these inputs, built (outside the lock) if it is not cached.
    pub fn get_or_build(
        &self,
        display: &DisplayGeometry,
        wavefront: &ZernikeCoefficients,
        eye: EyePosition,
        options: &TransportOptions,
    ) -> Result<std::sync::Arc<TransportMatrix>, TransportError> {
        let key = serde_json::json!({
            "display": display, "wavefront": wavefront, "eye": eye,
            "sub_rays": options.sub_rays, "seed": options.seed,
            "oversample": options.retina_oversample, "terms": options.derivative_terms,
        })
        .to_string();
        {
            let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            g.tick += 1;
            let tick = g.tick;
            if let Some((m, t)) = g.entries.get_mut(&key) {
                *t = tick;
                let m = m.clone();
                g.hits += 1;
                return Ok(m);
            }
            g.misses += 1;
        }
        let m = std::sync::Arc::new(TransportMatrix::build(display, wavefront, eye, options)?);
        let size = m.memory_bytes();
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if size <= g.capacity_bytes {
            Self::evict(&mut g, size);
            g.tick += 1;
            let tick = g.tick;
            if g.entries.insert(key, (m.clone(), tick)).is_none() {
                g.used_bytes += size;
            }
        }
        Ok(m)
    }
}

/// Expands a per-hole image (X×Y values per band, `img[(y·X + x)·N + n]`) into a light field with every view of
/// a hole equal: what an ordinary 2D multiband display behind the barrier would show.
pub fn plain_light_field(display: &DisplayGeometry, per_hole: &[f32]) -> Vec<f32> {
    let n = display.n_bands();
    let mut l = vec![0f32; display.n_samples_per_band() * n];
    l.par_chunks_mut(n).enumerate().for_each(|(p, out)| {
        let (x, y, _, _) = display.sample_coords(p);
        let h = (y * display.holes_x + x) as usize;
        out.copy_from_slice(&per_hole[h * n..h * n + n]);
    });
    l
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::zernike::Prescription;
    use rand::{Rng, SeedableRng};

    fn tiny() -> DisplayGeometry {
        DisplayGeometry {
            holes_x: 16,
            holes_y: 12,
            ..DisplayGeometry::paper()
        }
    }

    fn coupling4() -> Vec<[f32; 3]> {
        vec![[0.9, 0.3, 0.0], [0.5, 0.8, 0.05], [0.1, 0.2, 0.9], [0.7, 0.1, 0.0]]
    }

    fn rand_vec(n: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rng.gen::<f32>()).collect()
    }

    fn dot(a: &[f32], b: &[f32]) -> f64 {
        a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum()
    }

    fn aberrated(pupil: f64) -> ZernikeCoefficients {
        let mut c = vec![0.0; 28];
        c[4] = 0.4;
        c[7] = 0.15;
        c[8] = -0.1;
        c[12] = 0.12;
        c[6] = 0.08;
        ZernikeCoefficients::new(pupil, c).unwrap()
    }

    #[test]
    fn cache_returns_the_same_operator_and_respects_its_bound() {
        let d = tiny();
        let cache = TransportCache::new(64 << 20);
        let w = aberrated(6.0);
        let a = cache
            .get_or_build(&d, &w, EyePosition::default(), &Default::default())
            .unwrap();
        let b = cache
            .get_or_build(&d, &w, EyePosition::default(), &Default::default())
            .unwrap();
        assert!(std::sync::Arc::ptr_eq(&a, &b));
        let moved = EyePosition {
            x_mm: 1.0,
            ..Default::default()
        };
        let c = cache.get_or_build(&d, &w, moved, &Default::default()).unwrap();
        assert!(!std::sync::Arc::ptr_eq(&a, &c));
        assert_eq!(cache.stats().0, 1);
        // A bound smaller than one operator evicts everything and caches nothing more.
        cache.set_capacity_bytes(1);
        assert_eq!(cache.stats().2, 0);
        let d2 = cache
            .get_or_build(&d, &w, EyePosition::default(), &Default::default())
            .unwrap();
        assert!(!std::sync::Arc::ptr_eq(&a, &d2));
        assert_eq!(cache.stats().2, 0);
    }

    #[test]
    fn adjoint_identity_holds() {
        // ⟨A L, y⟩ = ⟨L, Aᵀ y⟩ for random L, y; f32 accumulation: relative 1e-5.
        let d = tiny();
        let opts = TransportOptions {
            derivative_terms: vec![4, 7],
            ..Default::default()
        };
        let t = TransportMatrix::build(&d, &aberrated(6.0), EyePosition::default(), &opts).unwrap();
        let c = coupling4();
        let l = rand_vec(t.n_samples() * 4, 1);
        let y = rand_vec(t.n_pixels() * 3, 2);
        let mut al = vec![0f32; t.n_pixels() * 3];
        let mut aty = vec![0f32; t.n_samples() * 4];
        t.forward_lms(&l, &c, &mut al);
        t.adjoint_lms(&y, &c, &mut aty);
        let (lhs, rhs) = (dot(&al, &y), dot(&l, &aty));
        assert!((lhs - rhs).abs() <= 1e-5 * lhs.abs(), "{lhs} vs {rhs}");
        for k in 0..2 {
            t.derivative_forward_lms(k, &l, &c, &mut al);
            t.derivative_adjoint_lms(k, &y, &c, &mut aty);
            let (lhs, rhs) = (dot(&al, &y), dot(&l, &aty));
            assert!(
                (lhs - rhs).abs() <= 1e-4 * lhs.abs().max(1e-3),
                "term {k}: {lhs} vs {rhs}"
            );
        }
    }

    #[test]
    fn perfect_eye_sees_a_plain_image_sharp_and_at_its_own_brightness() {
        let d = tiny();
        let t = TransportMatrix::build(
            &d,
            &ZernikeCoefficients::zero(6.0),
            EyePosition::default(),
            &Default::default(),
        )
        .unwrap();
        let ident: Vec<[f32; 3]> = vec![[1.0, 0.0, 0.0]];
        let d1 = DisplayGeometry {
            projectors: d.projectors[..1].to_vec(),
            ..d.clone()
        };
        // A uniform plain image is seen at its own intensity away from the border: each hole's light sums to
        // exactly its value; what the jittered splats exchange with the neighbours balances only on average
        // (Monte-Carlo noise of 400 sub-rays per hole): within 1 %.
        let ones = vec![0.7f32; (d.holes_x * d.holes_y) as usize];
        let mut out = vec![0f32; t.n_pixels() * 3];
        t.forward_lms(&plain_light_field(&d1, &ones), &ident, &mut out);
        for y in 1..d.holes_y - 1 {
            for x in 1..d.holes_x - 1 {
                let seen = out[((y * d.holes_x + x) * 3) as usize];
                assert!((seen - 0.7).abs() < 0.007, "uniform at ({x},{y}): {seen}");
            }
        }
        // A checkerboard of holes: a perfect eye resolves it. Each landing lies within the hole aperture
        // (±0.04 mm = ±0.1 pixel), so the bilinear splat spills at most 10 % into the neighbours.
        let per_hole: Vec<f32> = (0..d.holes_x * d.holes_y)
            .map(|h| ((h % d.holes_x + h / d.holes_x) % 2) as f32)
            .collect();
        let l = plain_light_field(&d1, &per_hole);
        let mut out = vec![0f32; t.n_pixels() * 3];
        t.forward_lms(&l, &ident, &mut out);
        for y in 1..d.holes_y - 1 {
            for x in 1..d.holes_x - 1 {
                let h = (y * d.holes_x + x) as usize;
                let seen = out[h * 3];
                assert!(
                    (seen - per_hole[h]).abs() < 0.1,
                    "hole ({x},{y}): {seen} vs {}",
                    per_hole[h]
                );
            }
        }
        // Every hole sends light into the pupil (the blocks are aimed at the design eye).
        assert_eq!(t.stats.holes_seen, (d.holes_x * d.holes_y) as u64);
    }

    #[test]
    fn defocus_blur_diameter_matches_d_times_pupil_times_dioptres() {
        // One bright hole seen with 1 D of defocus: the blur disc on the display plane has diameter
        // d·D·ΔD = 500 mm × 6 mm × 1 D / 1000 = 3.0 mm. Measure it as the second moment: a uniform disc of
        // diameter b has ⟨r²⟩ = b²/8 (plus the hole and view-bin spread, which is small). Within 10 %.
        let d = DisplayGeometry {
            holes_x: 31,
            holes_y: 31,
            ..DisplayGeometry::paper()
        };
        let w = ZernikeCoefficients::from_prescription(
            &Prescription {
                sphere_d: -1.0,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            },
            6.0,
        );
        let opts = TransportOptions {
            sub_rays: 64,
            retina_oversample: 4,
            ..Default::default()
        };
        let t = TransportMatrix::build(&d, &w, EyePosition::default(), &opts).unwrap();
        let d1 = DisplayGeometry {
            projectors: d.projectors[..1].to_vec(),
            ..d.clone()
        };
        let mut per_hole = vec![0f32; (d.holes_x * d.holes_y) as usize];
        per_hole[(15 * d.holes_x + 15) as usize] = 1.0;
        let l = plain_light_field(&d1, &per_hole);
        let mut out = vec![0f32; t.n_pixels() * 3];
        t.forward_lms(&l, &[[1.0, 0.0, 0.0]], &mut out);
        let g = t.grid;
        let (mut m0, mut m2) = (0f64, 0f64);
        for r in 0..g.len() {
            let v = out[r * 3] as f64;
            let x = g.origin_mm[0] + (r as u32 % g.width) as f64 * g.pixel_mm;
            let y = g.origin_mm[1] + (r as u32 / g.width) as f64 * g.pixel_mm;
            m0 += v;
            m2 += v * (x * x + y * y);
        }
        let diameter = (8.0 * m2 / m0).sqrt();
        assert!((diameter - 3.0).abs() < 0.3, "blur diameter {diameter} mm");
        // All the hole's light that entered the pupil reaches the retina (energy is conserved): intensity
        // 1 over one hole's area, i.e. 16 retinal pixels of a quarter pitch.
        assert!((m0 / 16.0 - 1.0).abs() < 1e-3, "energy {m0}");
    }

    #[test]
    fn rays_stopped_by_the_pupil_are_accounted_for() {
        // Views are 1.2 mm apart at the pupil, each ~2.4 mm wide: a 3 mm pupil admits fewer sub-rays than a
        // 6 mm one, in proportion to the overlap of the view fan with the pupil disc, and never all.
        let d = tiny();
        let build = |p: f64| {
            TransportMatrix::build(
                &d,
                &ZernikeCoefficients::zero(p),
                EyePosition::default(),
                &Default::default(),
            )
            .unwrap()
            .stats
        };
        let (small, large) = (build(3.0), build(6.0));
        assert_eq!(small.sub_rays_traced, large.sub_rays_traced);
        assert!(small.sub_rays_in_pupil < large.sub_rays_in_pupil);
        assert!(large.sub_rays_in_pupil < large.sub_rays_traced);
        // Independent estimate: 5×5 views on a 1.2 mm grid, each a 1.2 mm square (the screen pixel scaled by
        // d/g) blurred by the 1.28 mm hole disc, light a 6×6 mm square at the pupil almost uniformly; a pupil
        // disc catches the fraction πr²/36 of it: 0.785 at 6 mm, 0.196 at 3 mm. Soft edges: within 15 %.
        let frac = |s: TransportStats| s.sub_rays_in_pupil as f64 / s.sub_rays_traced as f64;
        assert!((frac(large) / 0.785 - 1.0).abs() < 0.15, "{}", frac(large));
        assert!((frac(small) / 0.196 - 1.0).abs() < 0.15, "{}", frac(small));
        // An eye 40 mm off axis sees the display only through stray views: far fewer rays.
        let off = TransportMatrix::build(
            &d,
            &ZernikeCoefficients::zero(6.0),
            EyePosition {
                x_mm: 40.0,
                ..Default::default()
            },
            &Default::default(),
        )
        .unwrap()
        .stats;
        assert!(off.sub_rays_in_pupil < large.sub_rays_in_pupil / 10);
    }

    #[test]
    fn derivative_matches_finite_differences() {
        // (∂T/∂W_j)·L against [T(W + h e_j) − T(W − h e_j)]·L / 2h with the same jitter seed. Bilinear weights
        // are piecewise linear in W, so the difference is exact except for sub-rays crossing a pixel edge
        // within ±h (a fraction ~4·h·|∂f/∂W| ≈ 0.3 % of them at h = 1e-4 µm) and f32 rounding
        // (~3e-4 relative): relative error 2 % on the whole image.
        let d = tiny();
        let base = aberrated(6.0);
        let terms = vec![4, 5, 7, 12];
        let opts = TransportOptions {
            derivative_terms: terms.clone(),
            ..Default::default()
        };
        let t = TransportMatrix::build(&d, &base, EyePosition::default(), &opts).unwrap();
        let c = coupling4();
        let l = rand_vec(t.n_samples() * 4, 3);
        let h = 1e-4;
        for (k, &j) in terms.iter().enumerate() {
            let mut plus = base.clone();
            plus.coefficients_um[j] += h;
            let mut minus = base.clone();
            minus.coefficients_um[j] -= h;
            let plain = TransportOptions::default();
            let tp = TransportMatrix::build(&d, &plus, EyePosition::default(), &plain).unwrap();
            let tm = TransportMatrix::build(&d, &minus, EyePosition::default(), &plain).unwrap();
            let (mut yp, mut ym, mut yd) = (
                vec![0f32; t.n_pixels() * 3],
                vec![0f32; t.n_pixels() * 3],
                vec![0f32; t.n_pixels() * 3],
            );
            tp.forward_lms(&l, &c, &mut yp);
            tm.forward_lms(&l, &c, &mut ym);
            t.derivative_forward_lms(k, &l, &c, &mut yd);
            let fd: Vec<f64> = yp
                .iter()
                .zip(&ym)
                .map(|(a, b)| (*a as f64 - *b as f64) / (2.0 * h))
                .collect();
            let err: f64 = fd
                .iter()
                .zip(&yd)
                .map(|(a, b)| (a - *b as f64).powi(2))
                .sum::<f64>()
                .sqrt();
            let norm: f64 = fd.iter().map(|a| a * a).sum::<f64>().sqrt();
            assert!(norm > 0.0);
            assert!(err / norm < 0.02, "term {j}: relative error {}", err / norm);
        }
    }
}
