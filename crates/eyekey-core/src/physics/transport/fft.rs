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
    small_grid_of(views.iter(), holes, k)
}

/// [`small_grid_size`] of every view in `views` (several operators' on one grid: the widest extent each way).
fn small_grid_of<'a>(
    views: impl Iterator<Item = &'a ViewStencil> + Clone,
    holes: (usize, usize),
    k: usize,
) -> (usize, usize) {
    let nonempty = || views.clone().filter(|v| v.width > 0);
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
    shape: Shape,
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
    /// The plan for `views` on a display of `shape`; spectra are computed when first used.
    pub(crate) fn new(views: &[ViewStencil], shape: Shape, n_terms: usize, deferred: bool) -> Self {
        let k = shape.k;
        let (p, q) = small_grid_size(views, (shape.holes_x, shape.holes_y), k);
        Self {
            plan: FftPlan::new(p * k, q * k),
            small: FftPlan::new(p, q),
            shape,
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
        cell.get_or_init(|| kernel_spectra(&self.plan, views, term))
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
        let shape = self.shape;
        let spectra = view_spectra(&self.small, &shape, l, n_bands, band);
        let total = spectrum_product(&self.plan, &self.small, [(kernels, spectra.as_slice())].into_iter());
        write_image(&self.plan, &shape, total, c, accumulate, out);
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
        let shape = self.shape;
        let mut y_spec = Vec::new();
        image_spectrum(&self.plan, &shape, y, c, &mut y_spec);
        let (nu, nv, ny) = (shape.views_u, shape.views_v, shape.holes_y);
        assert_eq!(planes.len(), nu * nv * ny * stride, "planes length");
        planes.par_chunks_mut(ny * stride).enumerate().for_each_init(
            || (self.small.scratch(), vec![Complex32::default(); self.small.q]),
            |(s, folded), (v, plane)| {
                let spec = fold_correlation(&self.plan, &self.small, [(&kernels[v], &y_spec)].into_iter(), s, folded);
                view_plane(&self.small, &shape, spec, s, plane, stride);
            },
        );
    }
}

/// A display's counts as the products see them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Shape {
    pub(crate) holes_x: usize,
    pub(crate) holes_y: usize,
    pub(crate) views_u: usize,
    pub(crate) views_v: usize,
    /// Retinal pixels per hole.
    pub(crate) k: usize,
}

/// K̂_v / (P·Q) per view of `views` (or of their derivative `term`) on `plan`'s grid.
fn kernel_spectra(plan: &FftPlan, views: &[ViewStencil], term: Option<usize>) -> Vec<Vec<Complex32>> {
    let (p, q) = (plan.p, plan.q);
    let scale = 1.0 / (p * q) as f32;
    views
        .par_iter()
        .map_init(
            || plan.scratch(),
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
                let mut spec = vec![Complex32::default(); plan.h * q];
                let mut img = std::mem::take(&mut s.img);
                plan.forward(&mut img, 0..q, &mut spec, s);
                s.img = img;
                spec
            },
        )
        .collect()
}

/// FFT'(L_v) of every view v of one band of the light field `l` on the small grid, view after view
/// (`[v·h'·Q' ..]`).
fn view_spectra(small: &FftPlan, shape: &Shape, l: &[f32], n_bands: usize, band: usize) -> Vec<Complex32> {
    let (mut images, mut spectra) = (Vec::new(), Vec::new());
    view_spectra_into(small, shape, l, n_bands, band, &mut images, &mut spectra);
    spectra
}

/// [`view_spectra`] into `spectra`, with `images` as the views' padded images (both sized here and kept for
/// the next call).
fn view_spectra_into(
    small: &FftPlan,
    shape: &Shape,
    l: &[f32],
    n_bands: usize,
    band: usize,
    images: &mut Vec<f32>,
    spectra: &mut Vec<Complex32>,
) {
    let (ps, qs, hs) = (small.p, small.q, small.h);
    let (nx, ny, nu, nv) = (shape.holes_x, shape.holes_y, shape.views_u, shape.views_v);
    let frame_w = nx * nu;
    // Rows past the display's stay zero (the transforms read only rows below ny); the rows below it are
    // written whole here, since a transform leaves its input rows as scratch.
    images.resize(nu * nv * ps * qs, 0.0);
    spectra.resize(nu * nv * hs * qs, Complex32::default());
    // The views' samples on their small grids, gathered in one pass over the light field: each frame row
    // is read whole, where gathering one view at a time would read all of it once per view.
    images
        .par_chunks_mut(nu * ps * qs)
        .enumerate()
        .for_each(|(j, row_of_views)| {
            for y in 0..ny {
                let frame = &l[(y * nv + j) * frame_w * n_bands..][..frame_w * n_bands];
                for i in 0..nu {
                    let row = &mut row_of_views[i * ps * qs + y * ps..][..ps];
                    let (dst, tail) = row.split_at_mut(nx);
                    for (x, d) in dst.iter_mut().enumerate() {
                        *d = frame[(x * nu + i) * n_bands + band];
                    }
                    tail.fill(0.0);
                }
            }
        });
    spectra
        .par_chunks_mut(hs * qs)
        .zip(images.par_chunks_mut(ps * qs))
        .for_each_init(|| small.scratch(), |s, (spec, img)| small.forward(img, 0..ny, spec, s));
}

/// Σ Σ_v K̂_v · FFT(L_v↑) over the (kernels, view spectra) pairs given (each pair's kernels per view, its views'
/// [`view_spectra`]), in blocks of [`PRODUCT_COLUMNS`] columns of frequencies, where FFT(L_v↑)[fx, fy] =
/// FFT'(L_v)[fx mod P', fy mod Q'] and the columns past P'/2 follow from the spectrum's symmetry,
/// X[a, b] = conj(X[P' − a, −b]).
fn spectrum_product<'a>(
    plan: &FftPlan,
    small: &FftPlan,
    pairs: impl Iterator<Item = (&'a [Vec<Complex32>], &'a [Complex32])> + Clone + Send + Sync,
) -> Vec<Complex32> {
    let (ps, qs, hs) = (small.p, small.q, small.h);
    let q = plan.q;
    let mut total = vec![Complex32::default(); plan.h * q];
    // A task sums a block of `PRODUCT_COLUMNS` columns view by view, so that it reads each view's kernel (and
    // spectrum) as one run; every frequency's terms are added in the same order as column by column.
    total.par_chunks_mut(PRODUCT_COLUMNS * q).enumerate().for_each_init(
        || vec![Complex32::default(); qs],
        |mirrored, (block, acc_block)| {
            for (kernels, spectra) in pairs.clone() {
                for (v, kernel) in kernels.iter().enumerate() {
                    let spec = &spectra[v * hs * qs..(v + 1) * hs * qs];
                    for (j, acc) in acc_block.chunks_exact_mut(q).enumerate() {
                        let fx = block * PRODUCT_COLUMNS + j;
                        let a = fx % ps;
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
                        multiply_add_runs(acc, k_column, column);
                    }
                }
            }
        },
    );
    total
}

/// The columns of frequencies a task of [`spectrum_product`] sums together.
const PRODUCT_COLUMNS: usize = 8;

/// acc[i] += column[i mod Q'] · k_column[i]: a column of the spectrum product (a view's spectrum repeated k
/// times along y).
///
/// The same arithmetic compiled for avx2 where the CPU has it (no fused multiply-adds: Rust does not contract
/// a·b + c, so the sums are the same to the bit).
#[inline]
fn multiply_add_runs(acc: &mut [Complex32], k_column: &[Complex32], column: &[Complex32]) {
    #[inline(always)]
    fn any(acc: &mut [Complex32], k_column: &[Complex32], column: &[Complex32]) {
        for (a_run, k_run) in acc
            .chunks_exact_mut(column.len())
            .zip(k_column.chunks_exact(column.len()))
        {
            for ((a, kz), z) in a_run.iter_mut().zip(k_run).zip(column) {
                *a += z * kz;
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn avx2(acc: &mut [Complex32], k_column: &[Complex32], column: &[Complex32]) {
        any(acc, k_column, column)
    }
    #[cfg(target_arch = "x86_64")]
    if super::stencil::has_avx2_fma() {
        // SAFETY: the CPU has the features `avx2` is compiled for.
        return unsafe { avx2(acc, k_column, column) };
    }
    any(acc, k_column, column)
}

/// out[r·3 + a] (+)= c[a]·(the retinal image of the spectrum `total`, cropped to the display's grid).
fn write_image(
    plan: &FftPlan,
    shape: &Shape,
    mut total: Vec<Complex32>,
    c: [f32; 3],
    accumulate: bool,
    out: &mut [f32],
) {
    let mut s = plan.scratch();
    let mut img = std::mem::take(&mut s.img);
    let (w, h) = (shape.holes_x * shape.k, shape.holes_y * shape.k);
    let p = plan.p;
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

/// Ŷ of the coupled image ỹ = Σ_a c_a y_a, zero-padded onto `plan`'s grid, into `y_spec` (sized here).
fn image_spectrum(plan: &FftPlan, shape: &Shape, y: &[f32], c: [f32; 3], y_spec: &mut Vec<Complex32>) {
    let p = plan.p;
    let (w, h) = (shape.holes_x * shape.k, shape.holes_y * shape.k);
    let mut s = plan.scratch();
    let mut img = std::mem::take(&mut s.img);
    for gy in 0..h {
        for gx in 0..w {
            let px = &y[(gy * w + gx) * 3..(gy * w + gx) * 3 + 3];
            img[gy * p + gx] = c[0] * px[0] + c[1] * px[1] + c[2] * px[2];
        }
    }
    y_spec.resize(plan.h * plan.q, Complex32::default());
    plan.forward(&mut img, 0..h, y_spec, &mut s);
}

/// One view's correlation Σ conj(K̂_v)·Ŷ over the (kernel, image spectrum) pairs given, folded onto the small
/// grid (its spectrum there, in `s.spec`'s buffer, returned): sampling the correlation at the holes. Column fx
/// of the full spectrum folds onto fx mod P' and, as the conjugate of column P − fx (the spectrum of a real
/// image), onto (P − fx) mod P'.
fn fold_correlation<'a>(
    plan: &FftPlan,
    small: &FftPlan,
    pairs: impl Iterator<Item = (&'a Vec<Complex32>, &'a Vec<Complex32>)> + Clone,
    s: &mut Scratch,
    folded: &mut [Complex32],
) -> Vec<Complex32> {
    let (p, q) = (plan.p, plan.q);
    let (ps, qs, hs) = (small.p, small.q, small.h);
    let mut spec = std::mem::take(&mut s.spec);
    spec.iter_mut().for_each(|z| *z = Complex32::default());
    for fx in 0..plan.h {
        folded.iter_mut().for_each(|z| *z = Complex32::default());
        let at = fx * q..(fx + 1) * q;
        for (kernel, y_spec) in pairs.clone() {
            correlate_runs(folded, &y_spec[at.clone()], &kernel[at.clone()]);
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
    spec
}

/// folded[i mod Q'] += y_column[i] · conj(k_column[i]): a column of [`fold_correlation`], compiled for avx2 where
/// the CPU has it (the same sums to the bit, as [`multiply_add_runs`]).
#[inline]
fn correlate_runs(folded: &mut [Complex32], y_column: &[Complex32], k_column: &[Complex32]) {
    #[inline(always)]
    fn any(folded: &mut [Complex32], y_column: &[Complex32], k_column: &[Complex32]) {
        let qs = folded.len();
        for (y_run, k_run) in y_column.chunks_exact(qs).zip(k_column.chunks_exact(qs)) {
            for ((f, yz), kz) in folded.iter_mut().zip(y_run).zip(k_run) {
                *f += yz * kz.conj();
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn avx2(folded: &mut [Complex32], y_column: &[Complex32], k_column: &[Complex32]) {
        any(folded, y_column, k_column)
    }
    #[cfg(target_arch = "x86_64")]
    if super::stencil::has_avx2_fma() {
        // SAFETY: the CPU has the features `avx2` is compiled for.
        return unsafe { avx2(folded, y_column, k_column) };
    }
    any(folded, y_column, k_column)
}

/// The view's samples of a folded spectrum (consumed, its buffer returned to `s`): `plane[y·stride + x]` for
/// the display's holes (the rest of each row left as it is).
fn view_plane(
    small: &FftPlan,
    shape: &Shape,
    mut spec: Vec<Complex32>,
    s: &mut Scratch,
    plane: &mut [f32],
    stride: usize,
) {
    let (ps, nx) = (small.p, shape.holes_x);
    let mut img = std::mem::take(&mut s.img);
    small.inverse(&mut spec, 0..shape.holes_y, &mut img, s);
    for (r, row) in plane.chunks_exact_mut(stride).enumerate().take(shape.holes_y) {
        row[..nx].copy_from_slice(&img[r * ps..r * ps + nx]);
    }
    s.img = img;
    s.spec = spec;
}

/// Several observers' kernels of every band as spectra on one padded grid per band (docs/design.md §2.7,
/// "Shared transforms"): a product for all of them transforms the light field's views once (forward) and the
/// views of their adjoints' sum once (adjoint), where each observer's own FFT products ([`FftKernels`])
/// transform them once an observer. What is left per observer and band is the spectrum product and one
/// transform of the retinal image each way. The adjoint of a sum is the sum of the adjoints, and sampling
/// at the holes is linear, so the observers' correlations are added on the full grid and folded and
/// transformed once.
pub(crate) struct SharedSpectra {
    shape: Shape,
    /// Per band.
    bands: Vec<BandSpectra>,
}

/// One band's grid and every observer's kernels on it.
struct BandSpectra {
    plan: FftPlan,
    small: FftPlan,
    /// Per observer, per view: K̂_v / (P·Q).
    kernels: Vec<Vec<Vec<Complex32>>>,
}

/// The light field's views transformed once for every observer ([`SharedSpectra::transform`]): per band,
/// [`view_spectra`]; with the buffers of the adjoint's sum, all kept from one product to the next.
#[derive(Default)]
pub(crate) struct ViewSpectra {
    spectra: Vec<Vec<Complex32>>,
    images: Vec<Vec<f32>>,
    planes: Vec<f32>,
}

/// One observer's adjoint input transformed ([`SharedSpectra::image_spectra`]): per band, Ŷ of Σ_a c_a y_a
/// (its buffers kept from one product to the next).
#[derive(Default)]
pub(crate) struct ImageSpectra(Vec<Vec<Complex32>>);

impl SharedSpectra {
    /// The small grid (P', Q') of each band: the widest extent of every observer's kernels of that band.
    pub(crate) fn grids(shape: Shape, views: &[Vec<&[ViewStencil]>]) -> Vec<(usize, usize)> {
        let n_bands = views.first().map_or(0, |o| o.len());
        assert!(
            views.iter().all(|o| o.len() == n_bands),
            "every observer has every band"
        );
        (0..n_bands)
            .map(|n| {
                let all = views.iter().flat_map(|o| o[n].iter());
                small_grid_of(all, (shape.holes_x, shape.holes_y), shape.k)
            })
            .collect()
    }

    /// `views[o][n]`: observer o's kernels of band n (every observer on one display of `shape`), on the
    /// bands' [`Self::grids`].
    pub(crate) fn new(shape: Shape, views: &[Vec<&[ViewStencil]>], grids: &[(usize, usize)]) -> Self {
        let bands = grids
            .iter()
            .enumerate()
            .map(|(n, &(p, q))| {
                let plan = FftPlan::new(p * shape.k, q * shape.k);
                let kernels = views.iter().map(|o| kernel_spectra(&plan, o[n], None)).collect();
                BandSpectra {
                    plan,
                    small: FftPlan::new(p, q),
                    kernels,
                }
            })
            .collect();
        Self { shape, bands }
    }

    /// Whether products through one grid per band are expected to cost less than each operator's own (the
    /// flops of [`fft_is_cheaper`]'s model, per direction): the views' transforms once, and per observer the
    /// spectrum product and one transform on the shared grid, against each operator's stencils (`taps`) or
    /// its own FFTs (on its own grid `own_grid`), whichever it runs.
    pub(crate) fn pays(shape: Shape, grids: &[(usize, usize)], own: &[Vec<OwnCost>]) -> bool {
        let n_views = (shape.views_u * shape.views_v) as f64;
        let k = shape.k;
        let mut shared = 0.0;
        for &(p, q) in grids {
            let small = (p * q) as f64;
            let full = small * (k * k) as f64;
            shared += FFT_FLOP_COST * n_views * 2.5 * small * small.log2();
            shared += FFT_FLOP_COST * own.len() as f64 * (2.5 * full * full.log2() + 4.0 * full * n_views);
        }
        let separate: f64 = own.iter().flatten().map(|c| c.flops()).sum();
        shared < separate
    }

    /// Every band's views of `l` (`l[p·N + n]`, N bands) transformed, into `views` (its buffers reused).
    pub(crate) fn transform(&self, l: &[f32], views: &mut ViewSpectra) {
        let n_bands = self.bands.len();
        views.spectra.resize_with(n_bands, Vec::new);
        views.images.resize_with(n_bands, Vec::new);
        for (n, b) in self.bands.iter().enumerate() {
            view_spectra_into(
                &b.small,
                &self.shape,
                l,
                n_bands,
                n,
                &mut views.images[n],
                &mut views.spectra[n],
            );
        }
    }

    /// Observer o's S = Σ_n c_n ⊗ T_n L_n (`out[r·3 + a]`, overwritten) from the light field's `views`.
    pub(crate) fn forward(&self, o: usize, views: &ViewSpectra, coupling: &[[f32; 3]], out: &mut [f32]) {
        for (n, (b, c)) in self.bands.iter().zip(coupling).enumerate() {
            let pairs = [(b.kernels[o].as_slice(), views.spectra[n].as_slice())].into_iter();
            let total = spectrum_product(&b.plan, &b.small, pairs);
            write_image(&b.plan, &self.shape, total, *c, n > 0, out);
        }
    }

    /// The transforms of Σ_a c_na y_a per band n, into `out` (its buffers reused): an observer's adjoint input
    /// `y[r·3 + a]` for [`Self::adjoint`].
    pub(crate) fn image_spectra(&self, y: &[f32], coupling: &[[f32; 3]], out: &mut ImageSpectra) {
        out.0.resize_with(self.bands.len(), Vec::new);
        for ((b, c), spec) in self.bands.iter().zip(coupling).zip(&mut out.0) {
            image_spectrum(&b.plan, &self.shape, y, *c, spec);
        }
    }

    /// `out[p·N + n]` = 2μ·x + c·Σ_o (observer o's Σ_a c_na (T_nᵀ y_oa))_p, from every observer's
    /// [`Self::image_spectra`] (`images[o]`, in the observers' order); `buffers` holds the per-view sums (the
    /// [`ViewSpectra`] of the same product serves).
    pub(crate) fn adjoint(
        &self,
        images: &[&ImageSpectra],
        x: &[f32],
        mu: f32,
        c: f32,
        buffers: &mut ViewSpectra,
        out: &mut [f32],
    ) {
        let observers = self.bands.first().map_or(0, |b| b.kernels.len());
        assert_eq!(images.len(), observers, "one image per observer");
        let Shape {
            holes_x: nx,
            holes_y: ny,
            views_u: nu,
            views_v: nv,
            ..
        } = self.shape;
        let n_bands = self.bands.len();
        let n_views = nu * nv;
        assert_eq!(x.len(), nx * ny * n_views * n_bands, "light field length");
        assert_eq!(out.len(), x.len(), "gradient length");
        // Per band and view, the sum of the observers' correlations folded and transformed once.
        let planes = &mut buffers.planes;
        planes.resize(n_bands * n_views * ny * nx, 0.0);
        planes.par_chunks_mut(ny * nx).enumerate().for_each_init(
            || None,
            |slot: &mut Option<(usize, Scratch, Vec<Complex32>)>, (at, plane)| {
                let (n, v) = (at / n_views, at % n_views);
                let b = &self.bands[n];
                if slot.as_ref().is_none_or(|s| s.0 != n) {
                    *slot = Some((n, b.small.scratch(), vec![Complex32::default(); b.small.q]));
                }
                let (_, s, folded) = slot.as_mut().expect("set above");
                let pairs = b.kernels.iter().zip(images).map(|(k, y)| (&k[v], &y.0[n]));
                let spec = fold_correlation(&b.plan, &b.small, pairs, s, folded);
                view_plane(&b.small, &self.shape, spec, s, plane, nx);
            },
        );
        let frame_w = nx * nu;
        out.par_chunks_mut(frame_w * n_bands)
            .zip(x.par_chunks(frame_w * n_bands))
            .enumerate()
            .for_each(|(row, (dst, x))| {
                let (yy, j) = (row / nv, row % nv);
                for i in 0..nu {
                    for n in 0..n_bands {
                        let from = ((n * n_views + j * nu + i) * ny + yy) * nx;
                        for (xx, g) in planes[from..from + nx].iter().enumerate() {
                            let at = (xx * nu + i) * n_bands + n;
                            dst[at] = 2.0 * mu * x[at] + c * g;
                        }
                    }
                }
            });
    }
}

/// What one operator's own products cost, for [`SharedSpectra::pays`].
#[derive(Clone, Copy, Debug)]
pub(crate) enum OwnCost {
    /// By stencils: their multiply-adds.
    Stencil { taps: usize },
    /// By its own FFTs on a P×Q grid.
    Fft {
        n_views: usize,
        p: usize,
        q: usize,
        k: usize,
    },
}

impl OwnCost {
    fn flops(self) -> f64 {
        match self {
            OwnCost::Stencil { taps } => 2.0 * taps as f64,
            OwnCost::Fft { n_views, p, q, k } => FFT_FLOP_COST * fft_flops(n_views, p, q, k),
        }
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
    FFT_FLOP_COST * fft_flops(n_views, p, q, k) < 2.0 * taps as f64
}

/// How much an FFT product's flop weighs against a stencil's multiply-add ([`fft_is_cheaper`]).
const FFT_FLOP_COST: f64 = 3.0;

/// The flops of one FFT product (either direction) on the P×Q grid: a real 2D FFT takes about 2.5·N·log2(N)
/// flops, the spectrum product 8 flops per held frequency (N/2).
fn fft_flops(n_views: usize, p: usize, q: usize, k: usize) -> f64 {
    let n = (p * q) as f64;
    let small = n / (k * k) as f64;
    n_views as f64 * (2.5 * small * small.log2() + 4.0 * n) + 2.5 * n * n.log2()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Σ Σ_v K̂_v · FFT(L_v↑) one full column at a time, view after view: [`spectrum_product`]'s sums as
    /// written from the module's equation, without its blocks or vector code.
    fn column_by_column(
        plan: &FftPlan,
        small: &FftPlan,
        pairs: &[(Vec<Vec<Complex32>>, Vec<Complex32>)],
    ) -> Vec<Complex32> {
        let (ps, qs, hs) = (small.p, small.q, small.h);
        let q = plan.q;
        let mut total = vec![Complex32::default(); plan.h * q];
        for (fx, acc) in total.chunks_exact_mut(q).enumerate() {
            let a = fx % ps;
            for (kernels, spectra) in pairs {
                for (v, kernel) in kernels.iter().enumerate() {
                    let spec = &spectra[v * hs * qs..(v + 1) * hs * qs];
                    let column: Vec<Complex32> = if a < hs {
                        spec[a * qs..(a + 1) * qs].to_vec()
                    } else {
                        let mirror = &spec[(ps - a) * qs..(ps - a + 1) * qs];
                        (0..qs).map(|b| conj_negated(mirror, b)).collect()
                    };
                    for (fy, z) in acc.iter_mut().enumerate() {
                        *z += column[fy % qs] * kernel[fx * q + fy];
                    }
                }
            }
        }
        total
    }

    #[test]
    fn the_correlation_runs_are_the_plain_loops_sums() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        let mut z = || Complex32::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
        // Q' of 1, 7 (a vector's remainder) and 120, repeated k = 1 and 3 times along the column.
        for (qs, k) in [(1, 1), (7, 3), (120, 1), (120, 3)] {
            let start: Vec<Complex32> = (0..qs).map(|_| z()).collect();
            let y: Vec<Complex32> = (0..qs * k).map(|_| z()).collect();
            let kernel: Vec<Complex32> = (0..qs * k).map(|_| z()).collect();
            let mut folded = start.clone();
            correlate_runs(&mut folded, &y, &kernel);
            let mut plain = start;
            for i in 0..qs * k {
                plain[i % qs] += y[i] * kernel[i].conj();
            }
            for (b, (f, p)) in folded.iter().zip(&plain).enumerate() {
                assert!(
                    f.re.to_bits() == p.re.to_bits() && f.im.to_bits() == p.im.to_bits(),
                    "Q' {qs}, k {k}, frequency {b}: {f} against {p}"
                );
            }
        }
    }

    #[test]
    fn the_blocked_spectrum_product_adds_in_the_columns_order() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut z = || Complex32::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
        // k = 1 (the `paper` preset's grids) and k = 3 (columns past P'/2 mirrored); P' odd and even, more
        // columns than a block and a last block cut short.
        for (ps, qs, k) in [(30, 24, 1), (15, 10, 3), (12, 9, 3)] {
            let (plan, small) = (FftPlan::new(ps * k, qs * k), FftPlan::new(ps, qs));
            let n_views = 5;
            let pairs: Vec<(Vec<Vec<Complex32>>, Vec<Complex32>)> = (0..2)
                .map(|_| {
                    let kernels = (0..n_views)
                        .map(|_| (0..plan.h * plan.q).map(|_| z()).collect())
                        .collect();
                    (kernels, (0..n_views * small.h * small.q).map(|_| z()).collect())
                })
                .collect();
            let blocked = spectrum_product(&plan, &small, pairs.iter().map(|(k, s)| (k.as_slice(), s.as_slice())));
            let reference = column_by_column(&plan, &small, &pairs);
            assert!(plan.h > PRODUCT_COLUMNS, "more than one block");
            assert_eq!(blocked.len(), reference.len());
            for (i, (b, r)) in blocked.iter().zip(&reference).enumerate() {
                assert!(
                    b.re.to_bits() == r.re.to_bits() && b.im.to_bits() == r.im.to_bits(),
                    "P' {ps}, Q' {qs}, k {k}: frequency {i}: {b} against {r}"
                );
            }
        }
    }
}
