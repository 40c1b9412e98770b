//! The per-view convolutions of the wave operator, T_n L = Σ_v K_v ⊛ L_v, applied by FFT (docs/design.md §2.7):
//! the convolution theorem on a zero-padded grid (Oppenheim & Schafer, *Discrete-Time Signal Processing*,
//! §8.7: circular convolution of length P equals linear convolution when P ≥ the signal's length plus the
//! kernel's).
//!
//! View v's samples sit at retinal pixels (x·k, y·k) and spread to (x·k + dx, y·k + dy) with weight K_v(dx, dy);
//! taps that land off the W×H retinal grid are dropped. On a P×Q grid with P ≥ max(W − k + max dx + 1, W − min dx)
//! (and the same in y) no tap that lands on the grid wraps onto another grid pixel and no off-grid tap wraps onto
//! the grid, so
//!
//! - forward: T L = crop(IFFT(Σ_v K̂_v · FFT(L_v↑))), with L_v↑ view v's samples placed at (x·k, y·k);
//! - adjoint: (Tᵀ ỹ)_v = sample(IFFT(conj(K̂_v) · FFT(ỹ padded))) at (x·k, y·k), the correlation with K_v.
//!
//! The grid is k times a smaller one, P = k·P' and Q = k·Q', and the views' transforms run on the small grid
//! (the DFT's decimation identities, Oppenheim & Schafer §4.6): a signal non-zero only at multiples of k has as
//! its P-point DFT the P'-point DFT of its samples repeated k times, FFT(L_v↑)[f] = FFT'(L_v)[f mod P']; and
//! sampling an inverse DFT at multiples of k is the P'-point inverse DFT of the spectrum folded onto P'
//! frequencies, sample(IFFT(Z))[x] = IFFT'(Σ_a Z[· + a·P'])[x]. So a product takes one transform per view on
//! k² times fewer points and one on the full grid.
//!
//! This is the same operator as the stencils (`super::stencil`), to rounding: a test checks both products
//! against them. Its cost is a few FFTs per view whatever the kernels' size, where the stencils' grows with
//! their taps, so large kernels (the `paper` and `dense` presets' diffraction-limited views) run faster
//! this way and small ones (lenslet) as stencils; [`fft_is_cheaper`] chooses.
//!
//! Spectra are real-to-complex along x (P/2 + 1 frequencies) and complex along y, held column-major
//! (`[f_x·Q + f_y]`) so that the y transforms run over contiguous memory. The kernels' spectra are computed on
//! the first product that needs them, each derivative term's separately.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};

use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};

use super::stencil::ViewStencil;

/// Transforms of one padded grid size.
pub(crate) struct FftPlan {
    /// Padded width (even) and height.
    p: usize,
    q: usize,
    /// x frequencies held, P/2 + 1.
    h: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
    col_forward: Arc<dyn Fft<f32>>,
    col_inverse: Arc<dyn Fft<f32>>,
}

/// The smallest n ≥ `at_least` whose only prime factors are 2, 3 and 5 (sizes the FFT runs fast on), even
/// when `even`.
fn smooth_size(at_least: usize, even: bool) -> usize {
    let mut n = at_least.max(2);
    loop {
        let mut m = n;
        for f in [2, 3, 5] {
            while m % f == 0 {
                m /= f;
            }
        }
        if m == 1 && (!even || n % 2 == 0) {
            return n;
        }
        n += 1;
    }
}

/// The small padded size P' along one axis (the full one is k·P'): `extent` retinal pixels, samples every
/// `k`, taps at offsets [lo, hi] (see the module's bound).
fn padded_size(extent: usize, k: usize, lo: i64, hi: i64, even: bool) -> usize {
    let e = extent as i64;
    let need = (e - k as i64 + hi + 1).max(e - lo).max(e);
    smooth_size((need as usize).div_ceil(k), even)
}

impl FftPlan {
    fn new(p: usize, q: usize) -> Self {
        let mut real = RealFftPlanner::<f32>::new();
        let mut complex = FftPlanner::<f32>::new();
        Self {
            p,
            q,
            h: p / 2 + 1,
            r2c: real.plan_fft_forward(p),
            c2r: real.plan_fft_inverse(p),
            col_forward: complex.plan_fft_forward(q),
            col_inverse: complex.plan_fft_inverse(q),
        }
    }

    /// Spectrum (column-major, h·q) of a real P×Q image of which only rows `rows` may be non-zero.
    fn forward(&self, img: &mut [f32], rows: impl Iterator<Item = usize>, spec: &mut [Complex32], s: &mut Scratch) {
        spec.iter_mut().for_each(|z| *z = Complex32::default());
        let (p, q) = (self.p, self.q);
        for y in rows {
            self.r2c
                .process_with_scratch(&mut img[y * p..(y + 1) * p], &mut s.row, &mut s.real)
                .expect("buffer sizes follow the plan");
            for (fx, z) in s.row.iter().enumerate() {
                spec[fx * q + y] = *z;
            }
        }
        // Every column at once: rustfft runs a buffer of several transforms in one call.
        self.col_forward.process_with_scratch(spec, &mut s.complex);
    }

    /// The real P×Q image of a spectrum (consumed), unnormalised; only rows `rows` are written to `img`.
    fn inverse(&self, spec: &mut [Complex32], rows: impl Iterator<Item = usize>, img: &mut [f32], s: &mut Scratch) {
        let (p, q, h) = (self.p, self.q, self.h);
        self.col_inverse.process_with_scratch(spec, &mut s.complex);
        for y in rows {
            for (fx, z) in s.row.iter_mut().enumerate() {
                *z = spec[fx * q + y];
            }
            // The spectrum of a real image: the DC and Nyquist terms of each row are real up to rounding.
            s.row[0].im = 0.0;
            s.row[h - 1].im = 0.0;
            self.c2r
                .process_with_scratch(&mut s.row, &mut img[y * p..(y + 1) * p], &mut s.real)
                .expect("buffer sizes follow the plan and the edge terms are real");
        }
    }

    fn scratch(&self) -> Scratch {
        let real_len = self.r2c.get_scratch_len().max(self.c2r.get_scratch_len());
        let complex_len = self
            .col_forward
            .get_inplace_scratch_len()
            .max(self.col_inverse.get_inplace_scratch_len());
        Scratch {
            row: vec![Complex32::default(); self.h],
            real: vec![Complex32::default(); real_len],
            complex: vec![Complex32::default(); complex_len],
            img: vec![0f32; self.p * self.q],
            spec: vec![Complex32::default(); self.h * self.q],
        }
    }
}

/// Per-thread buffers of the transforms.
struct Scratch {
    row: Vec<Complex32>,
    real: Vec<Complex32>,
    complex: Vec<Complex32>,
    img: Vec<f32>,
    spec: Vec<Complex32>,
}

/// The zero-padded grid (P, Q) on which the FFT products of `views` over holes.0 × holes.1 holes, k retinal
/// pixels per hole, equal the linear convolution (the module's bound), both multiples of k and P/k even;
/// planning nothing.
pub(crate) fn grid_size(views: &[ViewStencil], holes: (usize, usize), k: usize) -> (usize, usize) {
    let (p, q) = small_grid_size(views, holes, k);
    (p * k, q * k)
}

/// The small grid (P', Q') of the views' transforms: the padded grid is k times it.
fn small_grid_size(views: &[ViewStencil], holes: (usize, usize), k: usize) -> (usize, usize) {
    let nonempty = || views.iter().filter(|v| v.width > 0);
    let lo_x = nonempty().map(|v| v.x0).min().unwrap_or(0);
    let hi_x = nonempty().map(|v| v.x0 + v.width as i64 - 1).max().unwrap_or(0);
    let lo_y = nonempty().map(|v| v.y0).min().unwrap_or(0);
    let hi_y = nonempty().map(|v| v.y0 + v.height as i64 - 1).max().unwrap_or(0);
    (
        padded_size(holes.0 * k, k, lo_x, hi_x, true),
        padded_size(holes.1 * k, k, lo_y, hi_y, false),
    )
}

/// The kernels of one band (weights and each derivative term) as spectra on a padded grid.
pub(crate) struct FftKernels {
    /// The padded grid P×Q, of the kernels' spectra and the image's transforms.
    plan: FftPlan,
    /// The grid P/k × Q/k of the views' transforms.
    small: FftPlan,
    holes_x: usize,
    holes_y: usize,
    views_u: usize,
    views_v: usize,
    k: usize,
    /// K̂_v / (P·Q), per view.
    weights: OnceLock<Vec<Vec<Complex32>>>,
    /// Per term, per view.
    derivatives: Vec<OnceLock<Vec<Vec<Complex32>>>>,
    /// With `deferred`, products so far per term (weights first): the first runs by stencils, since computing
    /// the spectra costs about as much as a product, and an operator used once (a viewer's single view) is
    /// cheaper without them.
    deferred: bool,
    calls: Vec<AtomicU32>,
}

impl FftKernels {
    /// The plan for `views` over holes_x × holes_y holes with views_u × views_v views and k retinal pixels per
    /// hole; spectra are computed when first used.
    pub(crate) fn new(
        views: &[ViewStencil],
        holes: (usize, usize),
        view_counts: (usize, usize),
        k: usize,
        n_terms: usize,
        deferred: bool,
    ) -> Self {
        let (p, q) = small_grid_size(views, holes, k);
        Self {
            plan: FftPlan::new(p * k, q * k),
            small: FftPlan::new(p, q),
            holes_x: holes.0,
            holes_y: holes.1,
            views_u: view_counts.0,
            views_v: view_counts.1,
            k,
            weights: OnceLock::new(),
            derivatives: (0..n_terms).map(|_| OnceLock::new()).collect(),
            deferred,
            calls: (0..=n_terms).map(|_| AtomicU32::new(0)).collect(),
        }
    }

    /// Whether this product of `term` runs by FFT (always, unless deferred and it is the term's first).
    pub(crate) fn takes(&self, term: Option<usize>) -> bool {
        let calls = &self.calls[term.map_or(0, |t| t + 1)];
        !self.deferred || calls.fetch_add(1, Ordering::Relaxed) >= 1
    }

    /// Bytes of the spectra computed so far.
    pub(crate) fn memory_bytes(&self) -> usize {
        let bytes =
            |s: &OnceLock<Vec<Vec<Complex32>>>| s.get().map_or(0, |v| v.iter().map(|x| x.len() * 8).sum::<usize>());
        bytes(&self.weights) + self.derivatives.iter().map(bytes).sum::<usize>()
    }

    fn spectra(&self, views: &[ViewStencil], term: Option<usize>) -> &[Vec<Complex32>] {
        let cell = match term {
            None => &self.weights,
            Some(t) => &self.derivatives[t],
        };
        cell.get_or_init(|| {
            let (p, q) = (self.plan.p, self.plan.q);
            let scale = 1.0 / (p * q) as f32;
            views
                .par_iter()
                .map_init(
                    || self.plan.scratch(),
                    |s, st| {
                        let values = term.map_or(&st.weights, |t| &st.derivatives[t]);
                        s.img.iter_mut().for_each(|v| *v = 0.0);
                        for cy in 0..st.height {
                            let y = (st.y0 + cy as i64).rem_euclid(q as i64) as usize;
                            for cx in 0..st.width {
                                let x = (st.x0 + cx as i64).rem_euclid(p as i64) as usize;
                                s.img[y * p + x] += values[cy * st.width + cx] * scale;
                            }
                        }
                        let mut spec = vec![Complex32::default(); self.plan.h * q];
                        let mut img = std::mem::take(&mut s.img);
                        self.plan.forward(&mut img, 0..q, &mut spec, s);
                        s.img = img;
                        spec
                    },
                )
                .collect()
        })
    }

    /// out[r·3 + a] (+)= c[a]·(T L_band)_r, the light field's view v at `l[(frame index)·n_bands + band]`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn forward_band(
        &self,
        views: &[ViewStencil],
        term: Option<usize>,
        l: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        accumulate: bool,
        out: &mut [f32],
    ) {
        let kernels = self.spectra(views, term);
        let (plan, small) = (&self.plan, &self.small);
        let (p, q, k) = (plan.p, plan.q, self.k);
        let (ps, qs, hs) = (small.p, small.q, small.h);
        let (nx, ny, nu, nv) = (self.holes_x, self.holes_y, self.views_u, self.views_v);
        let frame_w = nx * nu;
        // The views' samples on their small grids, gathered in one pass over the light field: each frame row
        // is read whole, where gathering one view at a time would read all of it once per view.
        let mut images = vec![0f32; nu * nv * ps * qs];
        images
            .par_chunks_mut(nu * ps * qs)
            .enumerate()
            .for_each(|(j, row_of_views)| {
                for y in 0..ny {
                    let frame = &l[(y * nv + j) * frame_w * n_bands..][..frame_w * n_bands];
                    for i in 0..nu {
                        let dst = &mut row_of_views[i * ps * qs + y * ps..][..nx];
                        for (x, d) in dst.iter_mut().enumerate() {
                            *d = frame[(x * nu + i) * n_bands + band];
                        }
                    }
                }
            });
        let mut spectra = vec![Complex32::default(); nu * nv * hs * qs];
        spectra
            .par_chunks_mut(hs * qs)
            .zip(images.par_chunks_mut(ps * qs))
            .for_each_init(|| small.scratch(), |s, (spec, img)| small.forward(img, 0..ny, spec, s));
        // Σ_v K̂_v · FFT(L_v↑), one column of frequencies at a time, where FFT(L_v↑)[fx, fy] =
        // FFT'(L_v)[fx mod P', fy mod Q'] and the columns past P'/2 follow from the spectrum's symmetry,
        // X[a, b] = conj(X[P' − a, −b]).
        let mut total = vec![Complex32::default(); plan.h * q];
        total.par_chunks_mut(q).enumerate().for_each_init(
            || vec![Complex32::default(); qs],
            |mirrored, (fx, acc)| {
                let a = fx % ps;
                for (v, kernel) in kernels.iter().enumerate() {
                    let spec = &spectra[v * hs * qs..(v + 1) * hs * qs];
                    let column: &[Complex32] = if a < hs {
                        &spec[a * qs..(a + 1) * qs]
                    } else {
                        let mirror = &spec[(ps - a) * qs..(ps - a + 1) * qs];
                        for (b, m) in mirrored.iter_mut().enumerate() {
                            *m = conj_negated(mirror, b);
                        }
                        mirrored
                    };
                    let k_column = &kernel[fx * q..(fx + 1) * q];
                    for (a_run, k_run) in acc.chunks_exact_mut(qs).zip(k_column.chunks_exact(qs)) {
                        for ((a, kz), z) in a_run.iter_mut().zip(k_run).zip(column) {
                            *a += z * kz;
                        }
                    }
                }
            },
        );
        let mut s = plan.scratch();
        let mut img = vec![0f32; p * q];
        let (w, h) = (nx * k, ny * k);
        plan.inverse(&mut total, 0..h, &mut img, &mut s);
        out.par_chunks_mut(w * 3).enumerate().for_each(|(gy, row)| {
            for (gx, o) in row.chunks_exact_mut(3).enumerate() {
                let value = img[gy * p + gx];
                for (slot, ca) in o.iter_mut().zip(c) {
                    *slot = if accumulate { *slot + ca * value } else { ca * value };
                }
            }
        });
    }

    /// The adjoint of [`Self::forward_band`], Σ_a c[a]·(Tᵀ y_a), per view: sample (x, y; view v) at
    /// `planes[(v·ny + y)·stride + x]` (overwritten; the rest of each row left as it is).
    pub(crate) fn adjoint_planes(
        &self,
        views: &[ViewStencil],
        term: Option<usize>,
        y: &[f32],
        c: [f32; 3],
        stride: usize,
        planes: &mut [f32],
    ) {
        let kernels = self.spectra(views, term);
        let plan = &self.plan;
        let (p, q, k) = (plan.p, plan.q, self.k);
        let (nx, ny, nu, nv) = (self.holes_x, self.holes_y, self.views_u, self.views_v);
        let (w, h) = (nx * k, ny * k);
        // Ŷ of the coupled image ỹ = Σ_a c_a y_a, zero-padded.
        let mut s = plan.scratch();
        let mut img = vec![0f32; p * q];
        for gy in 0..h {
            for gx in 0..w {
                let px = &y[(gy * w + gx) * 3..(gy * w + gx) * 3 + 3];
                img[gy * p + gx] = c[0] * px[0] + c[1] * px[1] + c[2] * px[2];
            }
        }
        let mut y_spec = vec![Complex32::default(); plan.h * q];
        plan.forward(&mut img, 0..h, &mut y_spec, &mut s);
        // Per view: the correlation, sampled at the holes: its spectrum folded onto the small grid and
        // transformed there. Column fx of the full spectrum folds onto fx mod P' and, as the conjugate of
        // column P − fx (the spectrum of a real image), onto (P − fx) mod P'.
        let (ps, qs, hs) = (self.small.p, self.small.q, self.small.h);
        assert_eq!(planes.len(), nu * nv * ny * stride, "planes length");
        planes.par_chunks_mut(ny * stride).enumerate().for_each_init(
            || (self.small.scratch(), vec![Complex32::default(); qs]),
            |(s, folded), (v, plane)| {
                let mut spec = std::mem::take(&mut s.spec);
                spec.iter_mut().for_each(|z| *z = Complex32::default());
                for fx in 0..plan.h {
                    folded.iter_mut().for_each(|z| *z = Complex32::default());
                    let at = fx * q..(fx + 1) * q;
                    for (y_run, k_run) in y_spec[at.clone()].chunks_exact(qs).zip(kernels[v][at].chunks_exact(qs)) {
                        for ((f, yz), kz) in folded.iter_mut().zip(y_run).zip(k_run) {
                            *f += yz * kz.conj();
                        }
                    }
                    let a = fx % ps;
                    if a < hs {
                        for (z, f) in spec[a * qs..(a + 1) * qs].iter_mut().zip(folded.iter()) {
                            *z += f;
                        }
                    }
                    let mirror = (p - fx) % ps;
                    if fx != 0 && 2 * fx != p && mirror < hs {
                        for (b, z) in spec[mirror * qs..(mirror + 1) * qs].iter_mut().enumerate() {
                            *z += conj_negated(folded, b);
                        }
                    }
                }
                let mut img = std::mem::take(&mut s.img);
                self.small.inverse(&mut spec, 0..ny, &mut img, s);
                for (r, row) in plane.chunks_exact_mut(stride).enumerate() {
                    row[..nx].copy_from_slice(&img[r * ps..r * ps + nx]);
                }
                s.img = img;
                s.spec = spec;
            },
        );
    }
}

/// conj(X[−b]) of a spectrum's column X over Q' frequencies: the column at the mirrored x frequency of a real
/// image's spectrum.
fn conj_negated(column: &[Complex32], b: usize) -> Complex32 {
    column[(column.len() - b) % column.len()].conj()
}

/// Whether the FFT products are expected to beat the stencils for one band: `taps` multiply-adds of the
/// stencils against the transforms' work on the P×Q grid for `n_views` views with k retinal pixels per hole (a
/// forward transform per view on the (P/k)×(Q/k) grid, the spectrum product on the full one, and one inverse on
/// it; the adjoint mirrors it). The constant weighs an FFT's flop, with its memory passes and transposes,
/// against a stencil's register-resident multiply-add; it was measured by `eyekey bench --section wave`, which
/// times both on every preset. At 1 the `secure` and `lenslet` presets' products also run by FFT, 1.2–2× faster
/// alone, but the `secure` job then solved in 4.2 s against 4.3–4.9 s by stencils, held twice the memory
/// (1.9 GB: the spectra of 7 observers × 4 bands) and evaluated cached people in 5.5 s against 2.4 s.
pub(crate) fn fft_is_cheaper(taps: usize, n_views: usize, p: usize, q: usize, k: usize) -> bool {
    const FFT_FLOP_COST: f64 = 3.0;
    let n = (p * q) as f64;
    let small = n / (k * k) as f64;
    // A real 2D FFT: about 2.5·N·log2(N) flops; the spectrum product 8 flops per held frequency (N/2).
    let fft = n_views as f64 * (2.5 * small * small.log2() + 4.0 * n) + 2.5 * n * n.log2();
    FFT_FLOP_COST * fft < 2.0 * taps as f64
}
