//! Encoders (paper §6): turn objective images for several observers into one light field.
//!
//! * [`MultiplexObjective`]: Eq. 14 generalised to K weighted observers,
//!   Σ_k w_k ‖A_k L − S'_k‖² (+ μ‖L‖²/P, a mean-square Tikhonov term), A_k = C_k ⊗ T_k.
//! * [`DiffMaxObjective`]: Eq. 16, ‖A_t L − S'_t‖² − λ_W Σ_j ‖∂S_t/∂W_j‖² − λ_c ‖∂S_t/∂c‖², where
//!   ∂S_t/∂W_j = (C_t ⊗ ∂T/∂W_j) L (analytic, see [`crate::physics::transport`]) and ∂S_a/∂c_na = T L_n, so
//!   ‖∂S_t/∂c‖² = 3 Σ_n ‖T L_n‖². Non-convex; minimised by the monotone FISTA of [`crate::encoding::solver`].
//!   The combined encoder adds the multiplex terms of further observers to it.
//! * [`TiedViews`]: the spectral-only ablation, every view of a hole forced equal (a plain multiband display).
//!
//! Every term is divided by ‖S'_t‖² (the target's objective energy) so weights and λ's are relative.

use std::sync::Mutex;

use rayon::prelude::*;

use crate::encoding::leak::LeakPatterns;
use crate::encoding::solver::Objective;
use crate::physics::display::DisplayGeometry;
use crate::physics::observer::Observer;
use crate::physics::transport::{shared_spectra, ImageSpectra, SharedSpectra, StencilOperator, ViewSpectra};

/// One observer's least-squares term.
pub struct Term<'a> {
    pub observer: &'a Observer,
    /// What they should see, `[r·3 + a]` LMS.
    pub objective: Vec<f32>,
    /// Weight w_k (0 drops the least-squares part).
    pub weight: f64,
    /// The leak penalty ([`crate::encoding::leak`]) and its weight: `ω Σ_q Σ_a (q·(A_k L)_a)²`, normalised
    /// like the data terms.
    pub leak: Option<(&'a LeakPatterns, f64)>,
}

impl Term<'_> {
    /// The term's value at view `view` (unnormalised) and, in place, `view` turned into the gradient image
    /// ∂/∂view of it.
    fn value_and_gradient_image(&self, view: &mut [f32]) -> f64 {
        let leak = self.leak.map(|(p, w)| (p, w, p.project(view)));
        let mut f = 0.0;
        if self.weight > 0.0 {
            let w = self.weight;
            f += w * view
                .par_iter_mut()
                .zip(self.objective.par_iter())
                .map(|(a, b)| {
                    *a -= b;
                    let r = *a as f64;
                    *a *= (2.0 * w) as f32;
                    r * r
                })
                .sum::<f64>();
        } else {
            view.iter_mut().for_each(|v| *v = 0.0);
        }
        if let Some((p, w, c)) = leak {
            f += w * c.iter().map(|c| c * c).sum::<f64>();
            p.accumulate(&c, 2.0 * w, view);
        }
        f
    }

    /// The term's Hessian applied to a view: `view` becomes 2w·view + 2ω Σ (q·view) q.
    fn curvature_image(&self, view: &mut [f32]) {
        let leak = self.leak.map(|(p, w)| (p, w, p.project(view)));
        let w = (2.0 * self.weight) as f32;
        view.par_iter_mut().for_each(|v| *v *= w);
        if let Some((p, w, c)) = leak {
            p.accumulate(&c, 2.0 * w, view);
        }
    }
}

fn sq_norm(v: &[f32]) -> f64 {
    v.par_iter().map(|x| (*x as f64) * (*x as f64)).sum()
}

/// One term's scratch buffers, reused across evaluations (the solver calls the objective from one thread at a
/// time): its retinal image and its share of the gradient, as a light field or (where the light field is
/// gathered) as its adjoint's per-view planes.
struct Scratch {
    image: Vec<f32>,
    share: Vec<f32>,
    /// Where the terms' kernels are held on shared grids: the transforms of the term's adjoint input.
    spectra: ImageSpectra,
}

/// The light field gathered once for every term's forward products: its padding (the widest term's) and the
/// bands gathered (those some term reads by stencils).
struct Gather {
    pad: usize,
    bands: Vec<usize>,
}

impl Gather {
    /// What `terms` need gathered, if every one's operators are per-view kernels and some band's products run
    /// by stencils: only the bands some term's stencils read (FFT products read the light field as it is).
    fn of(terms: &[Term<'_>], n_bands: usize) -> Option<Self> {
        let mut by_stencils = vec![false; n_bands];
        for t in terms {
            for (any, own) in by_stencils.iter_mut().zip(t.observer.stencil_bands()) {
                *any |= own;
            }
        }
        let bands: Vec<usize> = (0..n_bands).filter(|&n| by_stencils[n]).collect();
        terms
            .iter()
            .map(|t| t.observer.gather_pad())
            .try_fold(0, |pad, p| p.map(|p| pad.max(p)))
            .filter(|_| !bands.is_empty())
            .map(|pad| Gather { pad, bands })
    }
}

/// Eq. 14, generalised to K observers, plus an optional Tikhonov term μ‖L‖²/P over the P unknowns.
pub struct MultiplexObjective<'a> {
    terms: Vec<Term<'a>>,
    n_unknowns: usize,
    scale: f64,
    tikhonov: f64,
    /// Where every term's operators are held as per-view kernels and some run by stencils: the light field is
    /// gathered once for all of them and their adjoints are added into the gradient per view, in one pass.
    gather: Option<Gather>,
    /// Where every term's operators are held as per-view kernels and one grid per band costs less than each
    /// term's own products: their kernels as spectra on it, so that the light field's views and the gradient's
    /// are transformed once for all terms (docs/design.md §2.7, "Shared transforms"). Takes the place of `gather`.
    shared: Option<SharedSpectra>,
    /// The shared path's transforms of the light field and per-view sums, kept from one product to the next.
    shared_buffers: Mutex<ViewSpectra>,
    scratch: Mutex<Vec<Scratch>>,
}

impl<'a> MultiplexObjective<'a> {
    /// Builds the objective; `reference_energy` (usually ‖S'_t‖²) normalises every data term, and the
    /// Tikhonov weight μ applies to the mean square of L.
    pub fn new(terms: Vec<Term<'a>>, n_bands: usize, reference_energy: f64, tikhonov: f64) -> Self {
        assert!(!terms.is_empty(), "at least one observer");
        let n_unknowns = terms[0].observer.n_samples() * n_bands;
        let tikhonov = tikhonov / n_unknowns.max(1) as f64;
        let stencils: Option<Vec<Vec<&StencilOperator>>> = terms.iter().map(|t| t.observer.band_stencils()).collect();
        let shared = stencils.and_then(|ops| shared_spectra(&ops, true));
        let gather = if shared.is_none() {
            Gather::of(&terms, n_bands)
        } else {
            None
        };
        let mut objective = Self {
            terms,
            n_unknowns,
            scale: 1.0 / reference_energy.max(1e-30),
            tikhonov,
            gather,
            shared,
            shared_buffers: Mutex::new(ViewSpectra::default()),
            scratch: Mutex::new(Vec::new()),
        };
        objective.make_scratch();
        objective
    }

    /// Each term's buffers, sized for the path its products take.
    fn make_scratch(&mut self) {
        let gathered = self.gather.is_some();
        let shared = self.shared.is_some();
        let scratch = self
            .terms
            .iter()
            .map(|t| Scratch {
                image: vec![0f32; t.observer.n_pixels() * 3],
                share: vec![
                    0f32;
                    if shared {
                        0
                    } else if gathered {
                        t.observer.planes_len()
                    } else {
                        self.n_unknowns
                    }
                ],
                spectra: ImageSpectra::default(),
            })
            .collect();
        *self.scratch.get_mut().unwrap_or_else(|e| e.into_inner()) = scratch;
    }

    pub fn terms(&self) -> &[Term<'a>] {
        &self.terms
    }

    /// Each term's weighted, normalised value at `l`: w_k‖A_k L − S'_k‖²/‖S'_t‖² plus its leak penalty.
    pub fn term_values(&self, l: &[f32]) -> Vec<f64> {
        self.terms
            .iter()
            .map(|t| {
                let mut view = t.observer.view(l);
                t.value_and_gradient_image(&mut view) * self.scale
            })
            .collect()
    }
}

impl Objective for MultiplexObjective<'_> {
    fn dim(&self) -> usize {
        self.n_unknowns
    }

    fn value_and_gradient(&self, l: &[f32], grad: &mut [f32]) -> f64 {
        let values = self.each_term(l, grad, |t, image| t.value_and_gradient_image(image));
        // Without a Tikhonov term (the default) ‖L‖² is not read: a pass over the unknowns per evaluation.
        let mut f = if self.tikhonov != 0.0 {
            self.tikhonov * sq_norm(l)
        } else {
            0.0
        };
        for v in values {
            f += self.scale * v;
        }
        f
    }

    fn curvature_product(&self, v: &[f32], out: &mut [f32]) {
        self.each_term(v, out, |t, image| {
            t.curvature_image(image);
            0.0
        });
    }
}

impl MultiplexObjective<'_> {
    /// For every term: its view of `x`, `at_view` turning it into the image whose adjoint is wanted (and giving
    /// the term's value), and that adjoint; then `out` = 2μ·x + Σ_k scale·(term k's adjoint). The terms run side
    /// by side (each product is itself parallel, and an idle thread takes over part of another term's), then
    /// their adjoints are added in the terms' order, as one term after another would. Where the light field is
    /// gathered once for all of them, their adjoints are kept per view and added in one pass (the same sums in
    /// the same order).
    fn each_term(&self, x: &[f32], out: &mut [f32], at_view: impl Fn(&Term<'_>, &mut [f32]) -> f64 + Sync) -> Vec<f64> {
        let mut scratch = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(shared) = &self.shared {
            return self.each_term_shared(shared, &mut scratch, x, out, at_view);
        }
        let source = self
            .gather
            .as_ref()
            .map(|g| self.terms[0].observer.gather(x, &g.bands, g.pad));
        let values = self
            .terms
            .par_iter()
            .zip(scratch.par_iter_mut())
            .map(|(t, Scratch { image, share, .. })| {
                match &source {
                    Some(source) => t.observer.forward_gathered(source, x, image),
                    None => t.observer.forward_lms(x, image),
                }
                let f = at_view(t, image);
                match &source {
                    Some(_) => t.observer.adjoint_planes(image, share),
                    None => t.observer.adjoint_lms(image, share),
                }
                f
            })
            .collect();
        if source.is_some() {
            let planes: Vec<&[f32]> = scratch.iter().map(|s| s.share.as_slice()).collect();
            self.terms[0]
                .observer
                .combine_planes(x, self.tikhonov as f32, self.scale as f32, &planes, out);
        } else {
            self.combine(x, &scratch, out);
        }
        values
    }

    /// [`Self::each_term`] through kernels held on one grid per band: the light field's views transformed once,
    /// each term's product and its adjoint input's transforms side by side, the adjoints' sum folded and
    /// transformed once per view. The same objective to rounding (the sums run in another order).
    fn each_term_shared(
        &self,
        shared: &SharedSpectra,
        scratch: &mut [Scratch],
        x: &[f32],
        out: &mut [f32],
        at_view: impl Fn(&Term<'_>, &mut [f32]) -> f64 + Sync,
    ) -> Vec<f64> {
        let mut views = self.shared_buffers.lock().unwrap_or_else(|e| e.into_inner());
        shared.transform(x, &mut views);
        let values = self
            .terms
            .par_iter()
            .enumerate()
            .zip(scratch.par_iter_mut())
            .map(|((o, t), s)| {
                shared.forward(o, &views, &t.observer.coupling, &mut s.image);
                let f = at_view(t, &mut s.image);
                shared.image_spectra(&s.image, &t.observer.coupling, &mut s.spectra);
                f
            })
            .collect();
        let images: Vec<&ImageSpectra> = scratch.iter().map(|s| &s.spectra).collect();
        shared.adjoint(&images, x, self.tikhonov as f32, self.scale as f32, &mut views, out);
        values
    }

    /// The same objective computed one term's light field at a time (the path for operators that are not all
    /// held as per-view kernels), to check the gathered path against.
    #[cfg(test)]
    fn without_gathering(mut self) -> Self {
        self.gather = None;
        self.shared = None;
        self.make_scratch();
        self
    }

    /// Whether the terms' kernels are held on one grid per band, their transforms shared.
    pub fn shares_transforms(&self) -> bool {
        self.shared.is_some()
    }

    /// The same objective without shared grids: the light field gathered once where some products run by
    /// stencils, each term's products on its own operators (what shared grids are measured against).
    pub fn without_shared_transforms(mut self) -> Self {
        if self.shared.take().is_some() {
            self.gather = Gather::of(&self.terms, self.terms[0].observer.coupling.len());
        }
        self.make_scratch();
        self
    }

    /// The same objective with its terms' kernels on shared grids whether or not that is expected to pay
    /// (every term's operators must be per-view kernels on one display).
    ///
    /// # Panics
    ///
    /// If some term's operators are not per-view kernels of every band, or the terms' displays differ.
    pub fn with_shared_transforms(mut self) -> Self {
        let ops: Vec<Vec<&StencilOperator>> = self
            .terms
            .iter()
            .map(|t| t.observer.band_stencils().expect("per-view kernels"))
            .collect();
        self.shared = Some(shared_spectra(&ops, false).expect("one display"));
        self.gather = None;
        self.make_scratch();
        self
    }

    /// `out` = 2μ·x + Σ_k scale·field_k, the terms added in order.
    fn combine(&self, x: &[f32], scratch: &[Scratch], out: &mut [f32]) {
        let mu = self.tikhonov as f32;
        let c = self.scale as f32;
        const CHUNK: usize = 4096;
        out.par_chunks_mut(CHUNK)
            .zip(x.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(n, (o, x))| {
                for (o, x) in o.iter_mut().zip(x) {
                    *o = 2.0 * mu * x;
                }
                for s in scratch {
                    for (o, v) in o.iter_mut().zip(&s.share[n * CHUNK..]) {
                        *o += c * v;
                    }
                }
            });
    }
}

/// Eq. 16 for the target, optionally plus multiplex terms for further observers (the combined encoder).
pub struct DiffMaxObjective<'a> {
    data: MultiplexObjective<'a>,
    target: &'a Observer,
    lambda_w: f64,
    lambda_c: f64,
    scale: f64,
    n_bands: usize,
}

impl<'a> DiffMaxObjective<'a> {
    /// `data` holds the target's term first (and any multiplex terms); the target's transport must carry the
    /// derivative terms ∂T/∂W_j to penalise. λ's are relative to ‖S'_t‖² like the data terms.
    pub fn new(data: MultiplexObjective<'a>, target: &'a Observer, lambda_w: f64, lambda_c: f64) -> Self {
        let scale = data.scale;
        let n_bands = target.coupling.len();
        Self {
            data,
            target,
            lambda_w,
            lambda_c,
            scale,
            n_bands,
        }
    }

    /// (‖∂S_t/∂W‖², ‖∂S_t/∂c‖²) at `l`, unnormalised.
    pub fn derivative_norms(&self, l: &[f32]) -> (f64, f64) {
        let t = self.target;
        let mut img = vec![0f32; t.n_pixels() * 3];
        let mut dw = 0.0;
        for k in 0..t.derivative_terms().len() {
            t.forward_with(Some(k), l, &t.coupling, &mut img);
            dw += sq_norm(&img);
        }
        let mut dc = 0.0;
        for sel in self.band_selectors() {
            t.forward_with(None, l, &sel, &mut img);
            dc += 3.0 * sq_norm(&img);
        }
        (dw, dc)
    }

    /// Couplings that route up to three bands at a time into the three output channels, so that
    /// T L_n for every band comes out of ⌈N/3⌉ fused products.
    fn band_selectors(&self) -> Vec<Vec<[f32; 3]>> {
        (0..self.n_bands.div_ceil(3))
            .map(|chunk| {
                (0..self.n_bands)
                    .map(|n| {
                        let mut row = [0f32; 3];
                        if n / 3 == chunk {
                            row[n % 3] = 1.0;
                        }
                        row
                    })
                    .collect()
            })
            .collect()
    }
}

impl Objective for DiffMaxObjective<'_> {
    fn dim(&self) -> usize {
        self.data.dim()
    }

    fn value_and_gradient(&self, l: &[f32], grad: &mut [f32]) -> f64 {
        let mut f = self.data.value_and_gradient(l, grad);
        let t = self.target;
        let mut img = vec![0f32; t.n_pixels() * 3];
        let mut field = vec![0f32; l.len()];
        // −λ_W Σ_j ‖D_j L‖²: gradient −2λ_W Σ_j D_jᵀ D_j L.
        if self.lambda_w != 0.0 {
            let c = (2.0 * self.lambda_w * self.scale) as f32;
            for k in 0..t.derivative_terms().len() {
                t.forward_with(Some(k), l, &t.coupling, &mut img);
                f -= self.lambda_w * self.scale * sq_norm(&img);
                t.adjoint_with(Some(k), &img, &t.coupling, &mut field);
                grad.par_iter_mut().zip(field.par_iter()).for_each(|(g, v)| *g -= c * v);
            }
        }
        // −λ_c · 3 Σ_n ‖T L_n‖²: gradient −6λ_c Tᵀ T L_n per band.
        if self.lambda_c != 0.0 {
            let c = (6.0 * self.lambda_c * self.scale) as f32;
            for sel in self.band_selectors() {
                t.forward_with(None, l, &sel, &mut img);
                f -= 3.0 * self.lambda_c * self.scale * sq_norm(&img);
                t.adjoint_with(None, &img, &sel, &mut field);
                grad.par_iter_mut().zip(field.par_iter()).for_each(|(g, v)| *g -= c * v);
            }
        }
        f
    }

    fn curvature_product(&self, v: &[f32], out: &mut [f32]) {
        // The derivative terms are concave: the data terms alone bound the curvature from above.
        self.data.curvature_product(v, out);
    }
}

/// The spectral-only ablation: unknowns are one value per hole and band; every view of a hole is equal.
pub struct TiedViews<'a, O: Objective + ?Sized> {
    inner: &'a O,
    display: &'a DisplayGeometry,
}

impl<'a, O: Objective + ?Sized> TiedViews<'a, O> {
    /// Wraps an objective over full light fields.
    pub fn new(inner: &'a O, display: &'a DisplayGeometry) -> Self {
        Self { inner, display }
    }

    /// The full light field of per-hole values `x[(y·X + x)·N + n]`.
    pub fn expand(&self, x: &[f32]) -> Vec<f32> {
        crate::physics::transport::plain_light_field(self.display, x)
    }

    /// Sum over the views of each hole (the adjoint of [`Self::expand`]).
    fn reduce(&self, full: &[f32], out: &mut [f32]) {
        let d = self.display;
        let n = d.n_bands();
        out.par_chunks_mut(n).enumerate().for_each(|(h, o)| {
            let (hx, hy) = (h as u32 % d.holes_x, h as u32 / d.holes_x);
            o.iter_mut().for_each(|v| *v = 0.0);
            for j in 0..d.views_v {
                for i in 0..d.views_u {
                    let p = d.sample_index(hx, hy, i, j);
                    for (b, v) in o.iter_mut().enumerate() {
                        *v += full[p * n + b];
                    }
                }
            }
        });
    }
}

impl<O: Objective + ?Sized> Objective for TiedViews<'_, O> {
    fn dim(&self) -> usize {
        (self.display.holes_x * self.display.holes_y) as usize * self.display.n_bands()
    }

    fn value_and_gradient(&self, x: &[f32], grad: &mut [f32]) -> f64 {
        let full = self.expand(x);
        let mut g = vec![0f32; full.len()];
        let f = self.inner.value_and_gradient(&full, &mut g);
        self.reduce(&g, grad);
        f
    }

    fn curvature_product(&self, v: &[f32], out: &mut [f32]) {
        let full = self.expand(v);
        let mut g = vec![0f32; full.len()];
        self.inner.curvature_product(&full, &mut g);
        self.reduce(&g, out);
    }
}

/// A high-contrast random mask the size of the retinal grid: independent black/white blocks of `block`
/// pixels, as linear RGB, to be shown to a decoy observer.
pub fn noise_decoy(width: u32, height: u32, block: u32, seed: u64) -> image::RgbImage {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let b = block.max(1);
    let (bw, bh) = (width.div_ceil(b), height.div_ceil(b));
    let cells: Vec<bool> = (0..bw * bh).map(|_| rng.gen()).collect();
    image::RgbImage::from_fn(width, height, |x, y| {
        let v = if cells[((y / b) * bw + x / b) as usize] { 255 } else { 0 };
        image::Rgb([v, v, v])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::solver::{minimise, SolverOptions};
    use crate::physics::observer::Optics;
    use crate::physics::profile::VisionProfile;
    use crate::physics::transport::{EyePosition, TransportCache, TransportOptions};
    use std::sync::atomic::AtomicBool;

    fn small_display() -> DisplayGeometry {
        DisplayGeometry {
            aperture: Default::default(),
            holes_x: 10,
            holes_y: 8,
            ..DisplayGeometry::paper()
        }
    }

    fn observer(d: &DisplayGeometry, c4: f64, c7: f64, terms: Vec<usize>, optics: Optics) -> Observer {
        let mut p = VisionProfile::perfect();
        p.zernike_um[4] = c4;
        p.zernike_um[7] = c7;
        let opts = TransportOptions {
            sub_rays: 8,
            derivative_terms: terms,
            ..Default::default()
        };
        Observer::new(
            d,
            &p,
            EyePosition::default(),
            &opts,
            optics,
            &TransportCache::disabled(),
        )
        .unwrap()
    }

    fn fd_check(obj: &dyn Objective, x: &[f32]) {
        // Directional derivatives against central differences in f64 accumulation, along an oscillating
        // direction (whose derivative cancels to ~1/1000 of ‖g‖·‖dir‖, more under wave optics, whose
        // operator is smoother) and a smooth one (no cancellation). The products are f32: the error allowed is
        // 1 % of the derivative plus 2·10⁻⁶ of ‖g‖·‖dir‖, about 2⁻²⁴ times the 30 or so terms each product
        // accumulates.
        let mut g = vec![0f32; x.len()];
        obj.value_and_gradient(x, &mut g);
        let oscillating: Vec<f32> = (0..x.len()).map(|i| ((i * 7919 % 13) as f32 - 6.0) / 6.0).collect();
        let smooth: Vec<f32> = (0..x.len()).map(|i| 1.0 + 0.5 * (i as f32 * 0.01).sin()).collect();
        let norm = |v: &[f32]| v.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
        for dir in [oscillating, smooth] {
            let h = 1e-2f32;
            let xp: Vec<f32> = x.iter().zip(&dir).map(|(a, d)| a + h * d).collect();
            let xm: Vec<f32> = x.iter().zip(&dir).map(|(a, d)| a - h * d).collect();
            let fd = (obj.value(&xp) - obj.value(&xm)) / (2.0 * h as f64);
            let an: f64 = g.iter().zip(&dir).map(|(a, b)| *a as f64 * *b as f64).sum();
            let allowed = 1e-2 * an.abs() + 2e-6 * norm(&g) * norm(&dir);
            assert!(
                (fd - an).abs() <= allowed,
                "fd {fd} vs analytic {an} (allowed {allowed})"
            );
        }
    }

    /// The target asked for `obj_t`; `r` as a decoy with a leak penalty; and `r` again as a leak-only decoy (no
    /// least-squares part at all).
    fn three_terms<'a>(t: &'a Observer, r: &'a Observer, obj_t: &[f32], leak: &'a LeakPatterns) -> Vec<Term<'a>> {
        vec![
            Term {
                observer: t,
                objective: obj_t.to_vec(),
                weight: 1.0,
                leak: None,
            },
            Term {
                observer: r,
                objective: vec![0.2; r.n_pixels() * 3],
                weight: 0.5,
                leak: Some((leak, 0.7)),
            },
            Term {
                observer: r,
                objective: vec![],
                weight: 0.0,
                leak: Some((leak, 2.0)),
            },
        ]
    }

    #[test]
    fn multiplex_and_diffmax_gradients_match_finite_differences() {
        // Under both forward models: wave optics gives every band its own operator (and its own ∂T/∂W_j).
        for optics in [Optics::Geometric, Optics::Wave] {
            check_gradients(optics);
        }
    }

    fn check_gradients(optics: Optics) {
        let d = small_display();
        let t = observer(&d, 0.1, 0.2, vec![4, 7, 12], optics);
        let r = observer(&d, -0.3, 0.0, vec![], optics);
        assert_eq!(t.per_band(), optics == Optics::Wave);
        let n = t.n_samples() * d.n_bands();
        let x: Vec<f32> = (0..n).map(|i| 0.3 + 0.4 * ((i * 31 % 17) as f32 / 17.0)).collect();
        let obj_t: Vec<f32> = (0..t.n_pixels() * 3).map(|i| (i % 5) as f32 * 0.1).collect();
        let energy = obj_t.iter().map(|v| (*v as f64).powi(2)).sum::<f64>();
        // A document on the retinal grid for the leak directions: a dark bar in a white field.
        let g = t.grid();
        let doc = image::RgbImage::from_fn(g.width, g.height, |x, y| {
            if (2..5).contains(&x) && y > 1 {
                image::Rgb([20, 20, 20])
            } else {
                image::Rgb([255, 255, 255])
            }
        });
        let leak = crate::encoding::leak::LeakPatterns::new(&doc, g.width, g.height, None, false);
        assert!(!leak.is_empty());
        let mk = || MultiplexObjective::new(three_terms(&t, &r, &obj_t, &leak), d.n_bands(), energy, 1e-3);
        fd_check(&mk(), &x);
        // The multiplex objective is quadratic: its curvature product is the gradient's exact difference.
        let m = mk();
        let v: Vec<f32> = (0..n).map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.05).collect();
        let (mut g0, mut g1, mut hv) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
        m.value_and_gradient(&x, &mut g0);
        let xv: Vec<f32> = x.iter().zip(&v).map(|(a, b)| a + b).collect();
        m.value_and_gradient(&xv, &mut g1);
        m.curvature_product(&v, &mut hv);
        let diff: Vec<f32> = g1.iter().zip(&g0).map(|(a, b)| a - b).collect();
        let err: f64 = diff
            .iter()
            .zip(&hv)
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        let scale = diff.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
        assert!(err <= 1e-3 * scale, "curvature {err} vs {scale}");
        let dm = DiffMaxObjective::new(mk(), &t, 0.05, 0.02);
        fd_check(&dm, &x);
        let tied = TiedViews::new(&dm, &d);
        let xt: Vec<f32> = (0..tied.dim()).map(|i| 0.2 + (i % 3) as f32 * 0.2).collect();
        fd_check(&tied, &xt);
    }

    /// What the tests of the objective's product paths evaluate, for target `t`'s display: the unknowns, a
    /// light field, a direction for the curvature product, the target's objective, and leak directions from a
    /// dark bar.
    fn paths_fixture(t: &Observer, n_bands: usize) -> (usize, Vec<f32>, Vec<f32>, Vec<f32>, LeakPatterns) {
        let n = t.n_samples() * n_bands;
        let x: Vec<f32> = (0..n).map(|i| 0.3 + 0.4 * ((i * 31 % 17) as f32 / 17.0)).collect();
        let v: Vec<f32> = (0..n).map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.05).collect();
        let obj_t: Vec<f32> = (0..t.n_pixels() * 3).map(|i| (i % 5) as f32 * 0.1).collect();
        let g = t.grid();
        let doc = image::RgbImage::from_fn(g.width, g.height, |x, _| image::Rgb([if x < 4 { 20 } else { 255 }; 3]));
        let leak = LeakPatterns::new(&doc, g.width, g.height, None, false);
        (n, x, v, obj_t, leak)
    }

    /// The gathered path (one light field gathered for every term, the adjoints combined per view) gives the
    /// value, gradient and curvature product of the one-term-at-a-time path bit for bit, with stencil and FFT
    /// products mixed.
    #[test]
    fn gathering_the_light_field_once_changes_no_bit() {
        use crate::physics::transport::ProductMethod;
        let d = small_display();
        // Some bands' products by FFT (as an operator's cost model may pick): band 0 for both (not gathered),
        // band 1 for one of them.
        let by = |o: Observer, fft_bands: usize| Observer {
            transports: o
                .transports
                .iter()
                .enumerate()
                .map(|(n, t)| {
                    let m = if n < fft_bands {
                        ProductMethod::Fft
                    } else {
                        ProductMethod::Stencil
                    };
                    std::sync::Arc::new(t.with_product_method(m))
                })
                .collect(),
            ..o
        };
        let t = by(observer(&d, 0.1, 0.2, vec![], Optics::Wave), 1);
        let r = by(observer(&d, -0.9, 0.0, vec![], Optics::Wave), 2);
        let (pt, pr) = (t.gather_pad().unwrap(), r.gather_pad().unwrap());
        assert_ne!(pt, pr, "operators of different padding read one gathered field");
        let (n, x, v, obj_t, leak) = paths_fixture(&t, d.n_bands());
        let mk = || MultiplexObjective::new(three_terms(&t, &r, &obj_t, &leak), d.n_bands(), 3.0, 1e-3);
        let (gathered, plain) = (mk().without_shared_transforms(), mk().without_gathering());
        let g = gathered.gather.as_ref().expect("a gathered light field");
        assert_eq!((g.pad, g.bands.as_slice()), (pt.max(pr), [1, 2, 3].as_slice()));
        let run = |o: &MultiplexObjective| {
            let (mut grad, mut hv) = (vec![0f32; n], vec![0f32; n]);
            let f = o.value_and_gradient(&x, &mut grad);
            o.curvature_product(&v, &mut hv);
            (
                f.to_bits(),
                grad.iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
                hv.iter().map(|h| h.to_bits()).collect::<Vec<_>>(),
            )
        };
        let (a, b) = (run(&gathered), run(&plain));
        assert!(a.1.iter().any(|g| *g != 0) && a.2.iter().any(|h| *h != 0));
        assert_eq!(a, b);
    }

    /// Kernels held on one grid per band for every term (the views' transforms shared) give the value,
    /// gradient and curvature product of the one-term-at-a-time path to rounding; and an objective picks them
    /// where they are expected to pay: many terms, not one.
    #[test]
    fn shared_grids_give_the_same_objective_to_rounding() {
        let d = small_display();
        let t = observer(&d, 0.1, 0.2, vec![], Optics::Wave);
        let r = observer(&d, -0.9, 0.0, vec![], Optics::Wave);
        let (n, x, v, obj_t, leak) = paths_fixture(&t, d.n_bands());
        let mk = || MultiplexObjective::new(three_terms(&t, &r, &obj_t, &leak), d.n_bands(), 3.0, 1e-3);
        let (shared, plain) = (mk().with_shared_transforms(), mk().without_gathering());
        let run = |o: &MultiplexObjective| {
            let (mut grad, mut hv) = (vec![0f32; n], vec![0f32; n]);
            let f = o.value_and_gradient(&x, &mut grad);
            o.curvature_product(&v, &mut hv);
            (f, grad, hv)
        };
        let (a, b) = (run(&shared), run(&plain));
        assert!((a.0 - b.0).abs() <= 1e-5 * b.0.abs(), "value {} against {}", a.0, b.0);
        for (what, u, w) in [("gradient", &a.1, &b.1), ("curvature", &a.2, &b.2)] {
            let largest = w.iter().fold(0f32, |m, g| m.max(g.abs()));
            assert!(largest > 0.0, "{what}");
            for (p, (u, w)) in u.iter().zip(w).enumerate() {
                assert!(
                    (u - w).abs() <= 1e-5 * largest,
                    "{what} {p}: {u} against {w} (largest {largest})"
                );
            }
        }
        // One term: one grid shares nothing, and its own products (the cheaper of stencils and its own FFTs)
        // cost at most as much. Twelve: the views' transforms, shared, cost less than twelve products.
        let some = |count: usize| {
            (0..count)
                .map(|i| Term {
                    observer: &r,
                    objective: obj_t.clone(),
                    weight: 0.1 * (i + 1) as f64,
                    leak: None,
                })
                .collect::<Vec<_>>()
        };
        assert!(MultiplexObjective::new(some(1), d.n_bands(), 3.0, 1e-3)
            .shared
            .is_none());
        assert!(MultiplexObjective::new(some(12), d.n_bands(), 3.0, 1e-3)
            .shared
            .is_some());
    }

    #[test]
    fn multiplex_shows_two_observers_two_different_images() {
        // Paper Fig. 11 in miniature: target and representative differ by 1 D of defocus; each is asked for a
        // different half-tone pattern, and each must end up closer to its own objective than to the other's.
        let d = small_display();
        let t = observer(&d, 0.0, 0.0, vec![], Optics::Geometric);
        let r = observer(&d, 1.3, 0.0, vec![], Optics::Geometric);
        let np = t.n_pixels();
        let pat_a: Vec<f32> = (0..np * 3).map(|i| if (i / 3) % 2 == 0 { 0.5 } else { 0.1 }).collect();
        let pat_b: Vec<f32> = (0..np * 3)
            .map(|i| if (i / 3 / 10) % 2 == 0 { 0.5 } else { 0.1 })
            .collect();
        let energy = pat_a.iter().map(|v| (*v as f64).powi(2)).sum::<f64>();
        let obj = MultiplexObjective::new(
            vec![
                Term {
                    observer: &t,
                    objective: pat_a.clone(),
                    weight: 1.0,
                    leak: None,
                },
                Term {
                    observer: &r,
                    objective: pat_b.clone(),
                    weight: 1.0,
                    leak: None,
                },
            ],
            d.n_bands(),
            energy,
            0.0,
        );
        let opts = SolverOptions {
            max_iterations: 300,
            ..Default::default()
        };
        let res = minimise(
            &obj,
            vec![0.5; obj.dim()],
            0.0,
            1.0,
            &opts,
            &mut |_| {},
            &AtomicBool::new(false),
        );
        let dist = |v: &[f32], p: &[f32]| v.iter().zip(p).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>();
        let (vt, vr) = (t.view(&res.x), r.view(&res.x));
        assert!(dist(&vt, &pat_a) < dist(&vt, &pat_b));
        assert!(dist(&vr, &pat_b) < dist(&vr, &pat_a));
        assert!(res.history.last().unwrap() < &res.history[0]);
    }

    #[test]
    fn noise_decoy_is_high_contrast() {
        let img = noise_decoy(40, 30, 2, 1);
        let black = img.pixels().filter(|p| p[0] == 0).count();
        assert!(black > 400 && black < 800, "{black}");
    }
}
