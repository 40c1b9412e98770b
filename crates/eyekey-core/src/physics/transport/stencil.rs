//! The shift-invariant wave operator applied as per-view stencils (docs/design.md §2.7): T_n L = Σ_v K_v ⊛ L_v.
//!
//! Sample (hole x, y; view v) sends its light to the retinal pixels (x·k + dx, y·k + dy) with weight
//! K_v(dx, dy), the same kernel for every hole of the view (k = retinal pixels per hole pitch). So T is held as
//! one dense box of weights per view (and one per derivative term ∂T/∂W_j), a few hundred KiB where the
//! expanded sparse form takes hundreds of MiB, and both products are sums of contiguous row operations:
//!
//! - forward, output row g_y: for every view v, kernel row c_y with (g_y − y0 − c_y) = y·k, and tap c_x,
//!   the output pixels of phase φ = (x0 + c_x) mod k receive K_v(c_x, c_y)·L_v(·, y) shifted by
//!   s = ⌊(x0 + c_x)/k⌋ holes: an AXPY over a whole row of holes;
//! - adjoint, sample row (v, y): the same pairs read the phase-φ pixels of the row g_y = y·k + y0 + c_y of the
//!   coupled image ỹ = Σ_a c_a y_a, shifted by s: an AXPY again.
//!
//! Taps that would land off the retinal grid are dropped, as in a traced T.

use std::sync::Arc;

use rayon::prelude::*;

use super::fft::{fft_is_cheaper, grid_size, FftKernels, OwnCost, Shape, SharedSpectra};
use crate::physics::display::DisplayGeometry;

/// One view's kernel: a dense box of weights (and of ∂/∂W_j per term) over retinal offsets
/// dx ∈ [x0, x0 + width), dy ∈ [y0, y0 + height) from a sample's hole origin (x·k, y·k).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ViewStencil {
    pub(crate) x0: i64,
    pub(crate) y0: i64,
    pub(crate) width: usize,
    pub(crate) height: usize,
    /// `height × width`, row-major.
    pub(crate) weights: Vec<f32>,
    /// One `height × width` box per derivative term.
    pub(crate) derivatives: Vec<Vec<f32>>,
}

impl ViewStencil {
    /// A box from (dx, dy, weight, ∂weight per term) taps; an empty list gives an empty box.
    pub(crate) fn from_taps(taps: &[(i64, i64, f32, &[f32])], n_terms: usize) -> Self {
        if taps.is_empty() {
            return Self {
                x0: 0,
                y0: 0,
                width: 0,
                height: 0,
                weights: Vec::new(),
                derivatives: vec![Vec::new(); n_terms],
            };
        }
        let (x0, x1) = taps
            .iter()
            .fold((i64::MAX, i64::MIN), |(lo, hi), t| (lo.min(t.0), hi.max(t.0)));
        let (y0, y1) = taps
            .iter()
            .fold((i64::MAX, i64::MIN), |(lo, hi), t| (lo.min(t.1), hi.max(t.1)));
        let (width, height) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
        let mut weights = vec![0f32; width * height];
        let mut derivatives = vec![vec![0f32; width * height]; n_terms];
        for &(dx, dy, w, dw) in taps {
            let cell = (dy - y0) as usize * width + (dx - x0) as usize;
            weights[cell] += w;
            for (d, v) in derivatives.iter_mut().zip(dw) {
                d[cell] += v;
            }
        }
        Self {
            x0,
            y0,
            width,
            height,
            weights,
            derivatives,
        }
    }

    fn values(&self, term: Option<usize>) -> &[f32] {
        term.map_or(&self.weights, |t| &self.derivatives[t])
    }
}

/// T (and ∂T/∂W_j) of one band as per-view stencils over a display's holes.
#[derive(Clone, PartialEq)]
pub struct StencilOperator {
    holes_x: usize,
    holes_y: usize,
    views_u: usize,
    views_v: usize,
    /// Retinal pixels per hole pitch.
    k: usize,
    /// Per view, index j·U + i.
    views: Vec<ViewStencil>,
    /// How the products lay out their rows, derived from the kernels once.
    layout: Layout,
    /// The same kernels as spectra, when the products run by FFT.
    fft: FftSlot,
}

/// How a wave operator's products are computed (the same operator either way, to rounding).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ProductMethod {
    /// Register-blocked stencils: work grows with the kernels' taps.
    Stencil,
    /// FFTs on a zero-padded grid: work grows with the grid, whatever the kernels' size.
    Fft,
}

/// The FFT form of a stencil operator, if its products use it; derived from the kernels, so two operators
/// with equal kernels are equal whatever their slots hold.
#[derive(Clone)]
struct FftSlot(Option<Arc<FftKernels>>);

impl PartialEq for FftSlot {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for StencilOperator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let largest = self
            .views
            .iter()
            .map(|v| (v.width, v.height))
            .max_by_key(|(w, h)| w * h);
        f.debug_struct("StencilOperator")
            .field("holes", &(self.holes_x, self.holes_y))
            .field("views", &(self.views_u, self.views_v))
            .field("k", &self.k)
            .field("largest_kernel", &largest)
            .field("bytes", &self.memory_bytes())
            .field("method", &self.method())
            .finish()
    }
}

/// Lanes of the register blocks: the output is computed 64 holes at a time (eight 256-bit registers, so eight
/// independent multiply-add chains per tap).
const LANES: usize = 64;

/// The taps of one kernel row that land on one output phase: cells c_x = c_0, c_0 + k, … of the row, whose
/// shifts in holes are s0, s0 + 1, …
#[derive(Clone, Debug, PartialEq)]
struct Group {
    phase: usize,
    s0: i64,
    /// Cell indices into the view's box, in order of c_x.
    cells: Vec<usize>,
}

/// A view's groups, indexed by kernel row.
fn groups(st: &ViewStencil, k: usize) -> Vec<Vec<Group>> {
    (0..st.height)
        .map(|cy| {
            (0..k)
                .filter_map(|phase| {
                    let cxs: Vec<usize> = (0..st.width)
                        .filter(|cx| (st.x0 + *cx as i64).rem_euclid(k as i64) as usize == phase)
                        .collect();
                    let first = *cxs.first()?;
                    Some(Group {
                        phase,
                        s0: (st.x0 + first as i64).div_euclid(k as i64),
                        cells: cxs.iter().map(|cx| cy * st.width + cx).collect(),
                    })
                })
                .collect()
        })
        .collect()
}

/// r[l] += w·s[l] over one register block; with `FMA`, fused (only where the CPU has it: `mul_add` is a
/// library call otherwise).
#[inline(always)]
fn madd<const FMA: bool, const B: usize>(r: &mut [f32; B], w: f32, s: &[f32]) {
    let s: &[f32; B] = s.try_into().expect("a block of B lanes");
    for (x, v) in r.iter_mut().zip(s) {
        *x = if FMA { w.mul_add(*v, *x) } else { *x + w * v };
    }
}

/// One group's taps on one block of B outputs of the forward product: dst[l] += Σ_j w_j·src[base − j + l],
/// with the B outputs held in registers (B/8 of 8 lanes) while the taps are added and written back once. Left
/// to the compiler, the forward product's loop ran one lane at a time (0.58 ms a band on `secure`, 0.40 ms
/// this way); the adjoint's, which it vectorises, is faster as it is (0.34 ms, 0.43 ms this way).
///
/// # Safety
///
/// Only for code compiled with avx2 and fma (the `*_avx2` functions) on a CPU that has them; `dst` holds B
/// floats and `src` every block read (base + B ≤ src.len(), base ≥ taps − 1), as the layout's padding
/// guarantees; B ≤ 64, a
/// multiple of 8.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn block_taps<const B: usize>(dst: &mut [f32], src: &[f32], base: usize, cells: &[usize], values: &[f32]) {
    use std::arch::x86_64::{
        __m256, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_set1_ps, _mm256_setzero_ps, _mm256_storeu_ps,
    };
    debug_assert!(B % 8 == 0 && B <= 64 && dst.len() >= B);
    let mut r: [__m256; 8] = [_mm256_setzero_ps(); 8];
    for (q, slot) in r.iter_mut().enumerate().take(B / 8) {
        *slot = _mm256_loadu_ps(dst.as_ptr().add(8 * q));
    }
    for (j, &cell) in cells.iter().enumerate() {
        let w = values[cell];
        if w == 0.0 {
            continue;
        }
        let at = base - j;
        debug_assert!(at + B <= src.len());
        let wv = _mm256_set1_ps(w);
        let p = src.as_ptr().add(at);
        for (q, slot) in r.iter_mut().enumerate().take(B / 8) {
            *slot = _mm256_fmadd_ps(wv, _mm256_loadu_ps(p.add(8 * q)), *slot);
        }
    }
    for (q, slot) in r.iter().enumerate().take(B / 8) {
        _mm256_storeu_ps(dst.as_mut_ptr().add(8 * q), *slot);
    }
}

/// The vector instructions the products are compiled for, chosen once at run time.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Simd {
    Avx2,
    Baseline,
}

fn simd() -> Simd {
    static SIMD: std::sync::OnceLock<Simd> = std::sync::OnceLock::new();
    *SIMD.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Simd::Avx2;
            }
        }
        Simd::Baseline
    })
}

/// Whether the CPU has the avx2 and fma instructions (checked once).
pub(crate) fn has_avx2_fma() -> bool {
    simd() == Simd::Avx2
}

/// The multiply-add peak of the vector code the products dispatch to, on every rayon thread, GFLOP/s (2 FLOPs
/// per multiply-add): 128 independent lanes of x ← a·x + b in sixteen 256-bit registers, the FMA units'
/// throughput with no loads or stores. The roofline `eyekey bench --section wave` measures against.
pub fn multiply_add_peak_gflops(steps: usize) -> f64 {
    // Baseline: the same 128 lanes as scalar code the compiler may vectorise as it can.
    fn chains(steps: usize, b: f32) -> f32 {
        let a = std::hint::black_box(0.999_999f32);
        let mut acc = [[1f32; 16]; 8];
        for _ in 0..steps {
            for chain in acc.iter_mut() {
                for x in chain.iter_mut() {
                    *x = a * *x + b;
                }
            }
        }
        acc.iter().flatten().sum()
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn chains_avx2(steps: usize, b: f32) -> f32 {
        use std::arch::x86_64::*;
        let (va, vb) = (_mm256_set1_ps(std::hint::black_box(0.999_999)), _mm256_set1_ps(b));
        let mut r = [_mm256_set1_ps(1.0); 16];
        for _ in 0..steps {
            for x in r.iter_mut() {
                *x = _mm256_fmadd_ps(va, *x, vb);
            }
        }
        let mut sum = [0f32; 8];
        let total = r.iter().fold(_mm256_setzero_ps(), |acc, x| _mm256_add_ps(acc, *x));
        // SAFETY: `sum` holds 8 f32, what one unaligned store of a 256-bit vector writes.
        unsafe { _mm256_storeu_ps(sum.as_mut_ptr(), total) };
        sum.iter().sum()
    }
    let threads = rayon::current_num_threads();
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let start = std::time::Instant::now();
        let sink: f32 = (0..threads)
            .into_par_iter()
            .map(|t| {
                let b = std::hint::black_box(1e-7 * (t + 1) as f32);
                match simd() {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `simd()` found the features the called function is compiled for.
                    Simd::Avx2 => unsafe { chains_avx2(steps, b) },
                    _ => chains(steps, b),
                }
            })
            .sum();
        std::hint::black_box(sink);
        best = best.min(start.elapsed().as_secs_f64());
    }
    (threads * steps * 128 * 2) as f64 / best / 1e9
}

/// The instruction set the products use: "avx2+fma" or "baseline".
pub fn vector_isa() -> &'static str {
    match simd() {
        Simd::Avx2 => "avx2+fma",
        Simd::Baseline => "baseline",
    }
}

/// One product's shared inputs: the operator, which values (T or ∂T/∂W_term), the tap groups, and the source
/// rows (the light field's per-view rows for the forward, the coupled image's per-phase rows for the adjoint),
/// each `row_len` long with its holes at [pad, pad + nx) and zeros around them (`pad` at least the layout's),
/// so that no block reads past a row and taps off the grid meet zeros.
struct Pass<'a> {
    op: &'a StencilOperator,
    term: Option<usize>,
    layout: &'a Layout,
    source: &'a [f32],
    pad: usize,
    row_len: usize,
}

impl Layout {
    /// The tap groups of every view, the padding their shifts need (holes each side of a source row), and the
    /// row lengths that follow, for rows of `holes_x` holes and `k` retinal pixels per hole.
    fn of(views: &[ViewStencil], k: usize, holes_x: usize) -> Self {
        let groups: Vec<Vec<Vec<Group>>> = views.iter().map(|v| groups(v, k)).collect();
        let pad = groups
            .iter()
            .flatten()
            .flatten()
            .map(|g| g.s0.unsigned_abs() as usize + g.cells.len())
            .max()
            .unwrap_or(0);
        // Register blocks as wide as a short row (so that a 32-hole row is not padded to 64), else LANES.
        let lanes = match holes_x {
            0..=16 => 16,
            17..=32 => 32,
            _ => LANES,
        };
        let nx_blocks = holes_x.div_ceil(lanes) * lanes;
        Self {
            groups,
            pad,
            lanes,
            nx_blocks,
            row_len: 2 * pad + nx_blocks,
        }
    }
}

/// How a product lays out its rows: the tap groups (per view, per kernel row), the zeros each side of a source
/// row, the output row rounded up to whole register blocks, and a source row's length.
#[derive(Clone, Debug, PartialEq)]
struct Layout {
    groups: Vec<Vec<Vec<Group>>>,
    pad: usize,
    /// Outputs per register block: 16, 32 or `LANES`.
    lanes: usize,
    nx_blocks: usize,
    row_len: usize,
}

/// Calls `$this.$method::<FMA, B>(args)` with B the layout's register block width (16, 32 or `LANES`).
macro_rules! by_lanes {
    ($lanes:expr, $this:ident . $method:ident :: <$fma:literal> ($($arg:expr),*)) => {
        match $lanes {
            16 => $this.$method::<$fma, 16>($($arg),*),
            32 => $this.$method::<$fma, 32>($($arg),*),
            _ => $this.$method::<$fma, LANES>($($arg),*),
        }
    };
}

impl Pass<'_> {
    /// Output rows gy, gy + 1, … of the forward product into `acc`, k·nx_blocks values a row (phase-major:
    /// phase φ's holes at [φ·nx_blocks, φ·nx_blocks + nx)).
    fn forward_rows(&self, gy: i64, acc: &mut [f32]) {
        match simd() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `simd()` found the features the called function is compiled for.
            Simd::Avx2 => unsafe { self.forward_rows_avx2(gy, acc) },
            _ => by_lanes!(self.layout.lanes, self.forward_rows_with::<false>(gy, acc)),
        }
    }

    /// Sample row `row` (= v·ny + y) of the adjoint product into `dst` (nx_blocks values, one per hole x).
    fn adjoint_row(&self, row: usize, dst: &mut [f32]) {
        match simd() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `simd()` found the features the called function is compiled for.
            Simd::Avx2 => unsafe { self.adjoint_row_avx2(row, dst) },
            _ => by_lanes!(self.layout.lanes, self.adjoint_row_with::<false>(row, dst)),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_rows_avx2(&self, gy: i64, acc: &mut [f32]) {
        by_lanes!(self.layout.lanes, self.forward_rows_with::<true>(gy, acc))
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn adjoint_row_avx2(&self, row: usize, dst: &mut [f32]) {
        by_lanes!(self.layout.lanes, self.adjoint_row_with::<true>(row, dst))
    }

    /// acc_φ[x'] += Σ_j w_j·L_v(x' − s0 − j, y) for every group, for the output rows gy, gy + 1, … that `acc`
    /// holds (k·nx_blocks values each, phase-major): view by view, so that a view's source rows stay in cache
    /// while every row of the chunk takes their light; each block of B outputs stays in registers while a
    /// group's taps are added.
    #[inline(always)]
    fn forward_rows_with<const FMA: bool, const B: usize>(&self, gy0: i64, acc: &mut [f32]) {
        let op = self.op;
        let groups = &self.layout.groups;
        let (pad, nb, row_len) = (self.pad, self.layout.nx_blocks, self.row_len);
        let (ny, k) = (op.holes_y, op.k as i64);
        let out_len = op.k * nb;
        for (v, st) in op.views.iter().enumerate() {
            let values = st.values(self.term);
            for (r, acc) in acc.chunks_exact_mut(out_len).enumerate() {
                // Kernel row cy adds source row y = (gy − y0 − cy)/k where that is a whole number in [0, ny):
                // the rows cy ≡ gy − y0 (mod k), stepping k, between the last source row and the first.
                let base = gy0 + r as i64 - st.y0;
                if base < 0 {
                    continue;
                }
                let first = base.rem_euclid(k).max(base - (ny as i64 - 1) * k);
                let last = base.min(groups[v].len() as i64 - 1);
                let mut cy = first + (base - first).rem_euclid(k);
                while cy <= last {
                    let row_groups = &groups[v][cy as usize];
                    let y = ((base - cy) / k) as usize;
                    cy += k;
                    let src = &self.source[(v * ny + y) * row_len..(v * ny + y + 1) * row_len];
                    for g in row_groups {
                        let base = (pad as i64 - g.s0) as usize;
                        let dst = &mut acc[g.phase * nb..(g.phase + 1) * nb];
                        #[cfg(target_arch = "x86_64")]
                        if FMA {
                            assert!(base + nb <= src.len() && base + 1 >= g.cells.len(), "a padded row");
                            for c in (0..nb).step_by(B) {
                                // SAFETY: `FMA` only in the avx2+fma functions; the blocks read lie within
                                // the padded row (checked above) and `dst` holds nb ≥ c + B floats.
                                unsafe { block_taps::<B>(&mut dst[c..], src, base + c, &g.cells, values) };
                            }
                            continue;
                        }
                        for c in (0..nb).step_by(B) {
                            let mut r: [f32; B] = dst[c..c + B].try_into().expect("a block");
                            for (j, &cell) in g.cells.iter().enumerate() {
                                let w = values[cell];
                                if w != 0.0 {
                                    let at = base + c - j;
                                    madd::<FMA, B>(&mut r, w, &src[at..at + B]);
                                }
                            }
                            dst[c..c + B].copy_from_slice(&r);
                        }
                    }
                }
            }
        }
    }

    /// dst[x] = Σ_groups Σ_j w_j·ỹ_φ(x + s0 + j, g_y), 64 samples at a time in registers.
    #[inline(always)]
    fn adjoint_row_with<const FMA: bool, const B: usize>(&self, row: usize, dst: &mut [f32]) {
        let op = self.op;
        let groups = &self.layout.groups;
        let (pad, nb, row_len) = (self.pad, self.layout.nx_blocks, self.row_len);
        let (ny, k) = (op.holes_y, op.k);
        let (v, yy) = (row / ny, row % ny);
        let st = &op.views[v];
        let values = st.values(self.term);
        for (cy, row_groups) in groups[v].iter().enumerate() {
            let gy = (yy * k) as i64 + st.y0 + cy as i64;
            if gy < 0 || gy >= (ny * k) as i64 {
                continue;
            }
            for g in row_groups {
                let at_row = (gy as usize * k + g.phase) * row_len;
                let src = &self.source[at_row..at_row + row_len];
                let base = (pad as i64 + g.s0) as usize;
                for c in (0..nb).step_by(B) {
                    let mut r: [f32; B] = dst[c..c + B].try_into().expect("a block");
                    for (j, &cell) in g.cells.iter().enumerate() {
                        let w = values[cell];
                        if w != 0.0 {
                            let at = base + c + j;
                            madd::<FMA, B>(&mut r, w, &src[at..at + B]);
                        }
                    }
                    dst[c..c + B].copy_from_slice(&r);
                }
            }
        }
    }
}

impl StencilOperator {
    pub(crate) fn new(display: &DisplayGeometry, k: u32, views: Vec<ViewStencil>) -> Self {
        assert_eq!(
            views.len(),
            (display.views_u * display.views_v) as usize,
            "one stencil per view"
        );
        let (k, holes_x) = (k.max(1) as usize, display.holes_x as usize);
        let layout = Layout::of(&views, k, holes_x);
        let mut op = Self {
            holes_x,
            holes_y: display.holes_y as usize,
            views_u: display.views_u as usize,
            views_v: display.views_v as usize,
            k,
            views,
            layout,
            fft: FftSlot(None),
        };
        op.choose_method();
        op
    }

    /// Uses the FFT products when [`fft_is_cheaper`] says so for these kernels.
    fn choose_method(&mut self) {
        let (p, q) = grid_size(&self.views, (self.holes_x, self.holes_y), self.k);
        let fft = fft_is_cheaper(self.nnz(), self.n_views(), p, q, self.k);
        self.fft = FftSlot(fft.then(|| Arc::new(self.fft_kernels(true))));
    }

    /// The FFT form of the kernels; `deferred`: each term's first product still runs by stencils.
    fn fft_kernels(&self, deferred: bool) -> FftKernels {
        let n_terms = self.views.first().map_or(0, |v| v.derivatives.len());
        FftKernels::new(&self.views, self.shape(), n_terms, deferred)
    }

    /// The display's counts as the products see them.
    fn shape(&self) -> Shape {
        Shape {
            holes_x: self.holes_x,
            holes_y: self.holes_y,
            views_u: self.views_u,
            views_v: self.views_v,
            k: self.k,
        }
    }

    /// What this operator's own products cost, by the method they run.
    fn own_cost(&self) -> OwnCost {
        match self.method() {
            ProductMethod::Stencil => OwnCost::Stencil { taps: self.nnz() },
            ProductMethod::Fft => {
                let (p, q) = grid_size(&self.views, (self.holes_x, self.holes_y), self.k);
                OwnCost::Fft {
                    n_views: self.n_views(),
                    p,
                    q,
                    k: self.k,
                }
            }
        }
    }

    /// How the products are computed.
    pub fn method(&self) -> ProductMethod {
        if self.fft.0.is_some() {
            ProductMethod::Fft
        } else {
            ProductMethod::Stencil
        }
    }

    /// The same operator with its products computed by `method` (from the first product on).
    pub fn with_method(&self, method: ProductMethod) -> Self {
        let mut op = self.clone();
        op.fft = FftSlot(match method {
            ProductMethod::Fft => Some(Arc::new(self.fft_kernels(false))),
            ProductMethod::Stencil => None,
        });
        op
    }

    /// Σ_q w_q·K_q per view (and per derivative term): the operator of light that is a mixture of the
    /// parts' wavelengths with power fractions w_q. All parts must share the display and the terms.
    pub(crate) fn mix(parts: &[(f64, &StencilOperator)]) -> Self {
        let first = parts[0].1;
        let views: Vec<ViewStencil> = (0..first.views.len())
            .map(|v| {
                let n_terms = first.views[v].derivatives.len();
                let mut taps: Vec<(i64, i64, f32, Vec<f32>)> = Vec::new();
                for &(w, op) in parts {
                    assert!(
                        op.holes_x == first.holes_x && op.views.len() == first.views.len() && op.k == first.k,
                        "mixed operators share the display"
                    );
                    let st = &op.views[v];
                    for cy in 0..st.height {
                        for cx in 0..st.width {
                            let cell = cy * st.width + cx;
                            let dw: Vec<f32> = st.derivatives.iter().map(|d| (w * d[cell] as f64) as f32).collect();
                            let value = (w * st.weights[cell] as f64) as f32;
                            if value != 0.0 || dw.iter().any(|x| *x != 0.0) {
                                taps.push((st.x0 + cx as i64, st.y0 + cy as i64, value, dw));
                            }
                        }
                    }
                }
                let refs: Vec<(i64, i64, f32, &[f32])> = taps.iter().map(|t| (t.0, t.1, t.2, t.3.as_slice())).collect();
                ViewStencil::from_taps(&refs, n_terms)
            })
            .collect();
        let mut op = Self {
            layout: Layout::of(&views, first.k, first.holes_x),
            views,
            ..first.clone()
        };
        op.choose_method();
        op
    }

    /// Light-field samples per band.
    pub fn n_samples(&self) -> usize {
        self.holes_x * self.holes_y * self.views_u * self.views_v
    }

    /// Retinal pixels.
    pub fn n_pixels(&self) -> usize {
        self.holes_x * self.holes_y * self.k * self.k
    }

    fn n_views(&self) -> usize {
        self.views_u * self.views_v
    }

    /// Bytes held by the kernels (and their spectra, once computed).
    pub fn memory_bytes(&self) -> usize {
        self.views
            .iter()
            .map(|v| 4 * v.weights.len() * (1 + v.derivatives.len()))
            .sum::<usize>()
            + self.fft.0.as_ref().map_or(0, |f| f.memory_bytes())
    }

    /// The multiply-adds of one band's product: every stored tap once per sample whose landing it keeps.
    pub fn nnz(&self) -> usize {
        let (w, h) = ((self.holes_x * self.k) as i64, (self.holes_y * self.k) as i64);
        let k = self.k as i64;
        // Holes x ∈ [0, n) with x·k + d ∈ [0, extent): x from ⌈−d/k⌉ to ⌊(extent − 1 − d)/k⌋.
        let count = |n: usize, d: i64, extent: i64| {
            let lo = (-d).div_euclid(k) + i64::from((-d).rem_euclid(k) != 0);
            let hi = (extent - 1 - d).div_euclid(k);
            (hi.min(n as i64 - 1) - lo.max(0) + 1).max(0) as usize
        };
        self.views
            .iter()
            .map(|v| {
                let mut total = 0;
                for cy in 0..v.height {
                    let ny = count(self.holes_y, v.y0 + cy as i64, h);
                    for cx in 0..v.width {
                        if v.weights[cy * v.width + cx] != 0.0 {
                            total += ny * count(self.holes_x, v.x0 + cx as i64, w);
                        }
                    }
                }
                total
            })
            .sum()
    }

    /// Sample `p`'s retinal pixels and weights (T's column p), off-grid taps dropped.
    pub fn column(&self, display: &DisplayGeometry, p: usize) -> Vec<(u32, f32)> {
        let (x, y, i, j) = display.sample_coords(p);
        let v = &self.views[j as usize * self.views_u + i as usize];
        let (w, h) = ((self.holes_x * self.k) as i64, (self.holes_y * self.k) as i64);
        let (ox, oy) = (x as i64 * self.k as i64, y as i64 * self.k as i64);
        let mut out = Vec::new();
        for cy in 0..v.height {
            for cx in 0..v.width {
                let (gx, gy) = (ox + v.x0 + cx as i64, oy + v.y0 + cy as i64);
                let value = v.weights[cy * v.width + cx];
                if value != 0.0 && (0..w).contains(&gx) && (0..h).contains(&gy) {
                    out.push(((gy * w + gx) as u32, value));
                }
            }
        }
        out
    }

    /// out[r·3 + a] (+)= c[a]·(T L_band)_r, or with `term` ∂T/∂W_term instead of T.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_band(
        &self,
        term: Option<usize>,
        l: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        accumulate: bool,
        out: &mut [f32],
    ) {
        self.forward_from(term, None, l, n_bands, band, c, accumulate, out);
    }

    /// The padding (holes each side of a source row) this operator's stencil products read: a
    /// [`GatheredField`] padded at least this much serves its forward product.
    pub fn gather_pad(&self) -> usize {
        self.layout.pad
    }

    /// Bands `bands` of the light field `l` laid out as the forward product reads them, padded by `pad` holes
    /// (at least [`Self::gather_pad`] of every operator that is to read it); the same for every operator on
    /// this display.
    pub fn gather(&self, l: &[f32], n_bands: usize, bands: &[usize], pad: usize) -> GatheredField {
        assert_eq!(l.len(), self.n_samples() * n_bands, "light field length");
        assert!(bands.iter().all(|b| *b < n_bands), "bands of the light field");
        let (nx, ny, nu, nv) = (self.holes_x, self.holes_y, self.views_u, self.views_v);
        let row_len = 2 * pad + self.layout.nx_blocks;
        let per_band = self.n_views() * ny * row_len;
        let mut rows = vec![0f32; bands.len() * per_band];
        let frame_w = nx * nu;
        // One task per (band, view row j): its U views' rows are contiguous; each frame row is read in order.
        rows.par_chunks_mut(nu * ny * row_len)
            .enumerate()
            .for_each(|(task, rows)| {
                let (band, j) = (bands[task / nv], task % nv);
                for y in 0..ny {
                    let frame = &l[(y * nv + j) * frame_w * n_bands..][..frame_w * n_bands];
                    // View by view, each destination row written in order: writing the U views' rows side by
                    // side would step `ny·row_len` floats between them, often a multiple of 4 KiB, and their
                    // streams would evict one another from the same cache sets.
                    for i in 0..nu {
                        let dst = &mut rows[(i * ny + y) * row_len + pad..][..nx];
                        for (d, s) in dst
                            .iter_mut()
                            .zip(frame[i * n_bands + band..].iter().step_by(nu * n_bands))
                        {
                            *d = *s;
                        }
                    }
                }
            });
        GatheredField {
            pad,
            row_len,
            shape: (nx, ny, nu, nv),
            bands: bands.to_vec(),
            per_band,
            rows,
        }
    }

    /// [`Self::forward_band`] of light field `l`'s band `band`, by stencils from `source` where it holds the
    /// band, `l` gathered once for every operator that reads it (the same sums in the same order, so the same
    /// image bit for bit), else from the band gathered here; by FFT from `l` where this operator's products run
    /// so.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_from(
        &self,
        term: Option<usize>,
        source: Option<&GatheredField>,
        l: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        accumulate: bool,
        out: &mut [f32],
    ) {
        assert_eq!(l.len(), self.n_samples() * n_bands, "light field length");
        assert_eq!(out.len(), self.n_pixels() * 3, "retinal image length");
        if let Some(f) = self.fft.0.as_ref().filter(|f| f.takes(term)) {
            return f.forward_band(&self.views, term, l, n_bands, band, c, accumulate, out);
        }
        match source.filter(|s| s.band(band).is_some()) {
            Some(source) => self.forward_gathered(term, source, band, c, accumulate, out),
            // A band no one else reads by stencils (or an FFT operator's first product, which runs by them).
            None => {
                let own = self.gather(l, n_bands, &[band], self.layout.pad);
                self.forward_gathered(term, &own, band, c, accumulate, out)
            }
        }
    }

    /// The stencils' forward product of band `band` from a gathered light field.
    fn forward_gathered(
        &self,
        term: Option<usize>,
        source: &GatheredField,
        band: usize,
        c: [f32; 3],
        accumulate: bool,
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), self.n_pixels() * 3, "retinal image length");
        let (nx, ny, nu, k) = (self.holes_x, self.holes_y, self.views_u, self.k);
        assert_eq!(source.shape, (nx, ny, nu, self.views_v), "gathered on this display");
        assert!(source.pad >= self.layout.pad, "gathered with this operator's padding");
        let nx_blocks = self.layout.nx_blocks;
        let pass = Pass {
            op: self,
            term,
            layout: &self.layout,
            source: source.band(band).expect("a gathered band"),
            pad: source.pad,
            row_len: source.row_len,
        };
        let width = nx * k;
        let rows_per_task = (ny * k / (4 * rayon::current_num_threads().max(1))).max(1);
        out.par_chunks_mut(rows_per_task * width * 3)
            .enumerate()
            .for_each(|(chunk, rows)| {
                let n_rows = rows.len() / (width * 3);
                let mut acc = vec![0f32; n_rows * k * nx_blocks];
                pass.forward_rows((chunk * rows_per_task) as i64, &mut acc);
                for (out_row, acc) in rows.chunks_exact_mut(width * 3).zip(acc.chunks_exact(k * nx_blocks)) {
                    // Retinal pixel g = x·k + φ is hole x's phase φ: one pass per phase, without dividing.
                    for (phase, acc) in acc.chunks_exact(nx_blocks).enumerate() {
                        let pixels = out_row[phase * 3..].chunks_mut(3).step_by(k);
                        for (o, value) in pixels.zip(&acc[..nx]) {
                            for (slot, ca) in o.iter_mut().zip(c) {
                                *slot = if accumulate { *slot + ca * value } else { ca * value };
                            }
                        }
                    }
                }
            });
    }

    /// The adjoint of [`Self::forward_band`]: out[p·N + band] = Σ_a c[a]·(Tᵀ y_a)_p; the other bands'
    /// entries are left as they are.
    #[allow(clippy::too_many_arguments)]
    pub fn adjoint_band(
        &self,
        term: Option<usize>,
        y: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), self.n_samples() * n_bands, "light field length");
        let mut planes = vec![0f32; self.plane_len()];
        self.adjoint_planes(term, y, c, &mut planes);
        scatter_views(
            out,
            &planes,
            self.plane_stride(),
            (self.holes_x, self.holes_y),
            (self.views_u, self.views_v),
            n_bands,
            band,
        );
    }

    /// Floats of one band's adjoint per view ([`Self::adjoint_planes`]): one row of `plane_stride` a (view, y).
    pub fn plane_len(&self) -> usize {
        self.n_views() * self.holes_y * self.layout.nx_blocks
    }

    /// Floats between a plane's rows.
    pub fn plane_stride(&self) -> usize {
        self.layout.nx_blocks
    }

    /// The adjoint of one band before it is written into the light field: `planes[((j·U + i)·ny + y)·stride +
    /// x]` = Σ_a c[a]·(Tᵀ y_a) of sample (x, y; view j·U + i), `stride` = [`Self::plane_stride`] (overwritten:
    /// what [`Self::adjoint_band`] writes into band `band`, by stencils or FFT as it would).
    pub fn adjoint_planes(&self, term: Option<usize>, y: &[f32], c: [f32; 3], planes: &mut [f32]) {
        assert_eq!(y.len(), self.n_pixels() * 3, "retinal image length");
        assert_eq!(planes.len(), self.plane_len(), "planes length");
        if let Some(f) = self.fft.0.as_ref().filter(|f| f.takes(term)) {
            return f.adjoint_planes(&self.views, term, y, c, self.plane_stride(), planes);
        }
        planes.fill(0.0);
        self.adjoint_planes_by_stencils(term, y, c, planes);
    }

    /// The stencils' [`Self::adjoint_planes`] (zeros in).
    fn adjoint_planes_by_stencils(&self, term: Option<usize>, y: &[f32], c: [f32; 3], planes: &mut [f32]) {
        let (nx, ny, k) = (self.holes_x, self.holes_y, self.k);
        let layout = &self.layout;
        let (pad, nx_blocks, row_len) = (layout.pad, layout.nx_blocks, layout.row_len);
        let width = nx * k;
        // ỹ = Σ_a c_a y_a as one padded row per (retinal row, phase).
        let mut source = vec![0f32; ny * k * k * row_len];
        source.par_chunks_mut(k * row_len).enumerate().for_each(|(gy, rows)| {
            let image_row = &y[gy * width * 3..(gy + 1) * width * 3];
            // Retinal pixel g = x·k + φ goes to phase φ's row at hole x: one pass per phase, without dividing.
            for (phase, row) in rows.chunks_exact_mut(row_len).enumerate() {
                let pixels = image_row[phase * 3..].chunks(3).step_by(k);
                for (d, px) in row[pad..pad + nx].iter_mut().zip(pixels) {
                    *d = c[0] * px[0] + c[1] * px[1] + c[2] * px[2];
                }
            }
        });
        let pass = Pass {
            op: self,
            term,
            layout,
            source: &source,
            pad,
            row_len,
        };
        planes
            .par_chunks_mut(nx_blocks)
            .enumerate()
            .for_each(|(row, dst)| pass.adjoint_row(row, dst));
    }

    /// `out[p·N + n]` = 2μ·x[p·N + n] + Σ_k c·(term k's band-n adjoint at sample p), the terms added in the
    /// order given: an objective's gradient from every term's [`Self::adjoint_planes`] (`planes[k]` holds term
    /// k's N bands one after another, each laid out as this operator's), written into the light field once
    /// instead of once a term. The same sums in the same order as writing each term's adjoint out
    /// ([`Self::adjoint_band`]) and adding the light fields, so the same gradient bit for bit.
    pub fn combine_planes(&self, x: &[f32], mu: f32, c: f32, planes: &[&[f32]], n_bands: usize, out: &mut [f32]) {
        let (nx, ny, nu, nv) = (self.holes_x, self.holes_y, self.views_u, self.views_v);
        let (stride, plane_len) = (self.plane_stride(), self.plane_len());
        assert_eq!(x.len(), self.n_samples() * n_bands, "light field length");
        assert_eq!(out.len(), x.len(), "gradient length");
        assert!(planes.iter().all(|p| p.len() == plane_len * n_bands), "planes length");
        let frame_w = nx * nu;
        out.par_chunks_mut(frame_w * n_bands)
            .zip(x.par_chunks(frame_w * n_bands))
            .enumerate()
            .for_each_init(
                || vec![0f32; nx],
                |acc, (row, (dst, x))| {
                    let (yy, j) = (row / nv, row % nv);
                    for n in 0..n_bands {
                        for i in 0..nu {
                            let at = |xx: usize| (xx * nu + i) * n_bands + n;
                            for (xx, a) in acc.iter_mut().enumerate() {
                                *a = 2.0 * mu * x[at(xx)];
                            }
                            let from = n * plane_len + ((j * nu + i) * ny + yy) * stride;
                            for p in planes {
                                for (a, v) in acc.iter_mut().zip(&p[from..from + nx]) {
                                    *a += c * v;
                                }
                            }
                            for (xx, a) in acc.iter().enumerate() {
                                dst[at(xx)] = *a;
                            }
                        }
                    }
                },
            );
    }
}

/// Several observers' operators (`ops[o][n]`: observer o's of band n) with their kernels as spectra on one
/// grid per band ([`SharedSpectra`]), when they share a display and, with `only_if_cheaper`, when that is
/// expected to cost less than each operator's own products; `None` otherwise.
pub(crate) fn shared_spectra(ops: &[Vec<&StencilOperator>], only_if_cheaper: bool) -> Option<SharedSpectra> {
    let first = ops.first()?.first()?;
    let shape = first.shape();
    let n_bands = ops[0].len();
    if ops
        .iter()
        .any(|o| o.len() != n_bands || o.iter().any(|op| op.shape() != shape))
    {
        return None;
    }
    let views: Vec<Vec<&[ViewStencil]>> = ops
        .iter()
        .map(|o| o.iter().map(|op| op.views.as_slice()).collect())
        .collect();
    let grids = SharedSpectra::grids(shape, &views);
    if only_if_cheaper {
        let own: Vec<Vec<OwnCost>> = ops.iter().map(|o| o.iter().map(|op| op.own_cost()).collect()).collect();
        if !SharedSpectra::pays(shape, &grids, &own) {
            return None;
        }
    }
    Some(SharedSpectra::new(shape, &views, &grids))
}

/// Bands of a light field laid out as the stencils' forward products read them ([`StencilOperator::gather`]):
/// per band, one row per (view, y) of `row_len` floats with the holes at [pad, pad + nx) and zeros around them.
pub struct GatheredField {
    pad: usize,
    row_len: usize,
    /// Holes across and down, views across and down.
    shape: (usize, usize, usize, usize),
    /// The bands gathered, in the order their rows are held.
    bands: Vec<usize>,
    per_band: usize,
    rows: Vec<f32>,
}

impl GatheredField {
    /// Band `band`'s rows, if it was gathered.
    fn band(&self, band: usize) -> Option<&[f32]> {
        let at = self.bands.iter().position(|b| *b == band)?;
        Some(&self.rows[at * self.per_band..(at + 1) * self.per_band])
    }
}

/// Writes band `band` of the light field `out` from per-view planes: sample (x, y; view j·U + i) takes
/// `planes[((j·U + i)·ny + y)·stride + x]`; the other bands' entries are left as they are.
fn scatter_views(
    out: &mut [f32],
    planes: &[f32],
    stride: usize,
    (nx, ny): (usize, usize),
    (nu, nv): (usize, usize),
    n_bands: usize,
    band: usize,
) {
    let frame_w = nx * nu;
    // Each frame row reads its views' plane rows whole, one view at a time: reading the views in the frame's
    // order instead would step through `ny·stride` floats between neighbours, often a multiple of 4 KiB, and
    // the views' streams would evict one another from the same cache sets.
    out.par_chunks_mut(frame_w * n_bands)
        .enumerate()
        .for_each(|(row, dst)| {
            let (yy, j) = (row / nv, row % nv);
            for i in 0..nu {
                let src = &planes[((j * nu + i) * ny + yy) * stride..][..nx];
                for (x, v) in src.iter().enumerate() {
                    dst[(x * nu + i) * n_bands + band] = *v;
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::transport::rng::SplitMix64;
    use crate::physics::transport::{ImageSpectra, ViewSpectra};

    /// Small displays with 3×2 views (geometry otherwise the paper's; only the counts matter): 5×4 holes (rows
    /// shorter than one register block) and 70×3 (rows of two blocks, the second part-filled).
    /// Rows of 5, 27 and 70 holes: register blocks of 16, 32 and 64 lanes (the last two blocks of them).
    fn displays() -> [DisplayGeometry; 3] {
        [(5, 4), (27, 3), (70, 3)].map(|(holes_x, holes_y)| DisplayGeometry {
            holes_x,
            holes_y,
            views_u: 3,
            views_v: 2,
            ..DisplayGeometry::paper()
        })
    }

    /// Random kernels: boxes that start left of, at and right of the hole origin and reach past the grid,
    /// with some zero taps, and one derivative term.
    fn operator(d: &DisplayGeometry, k: u32, seed: u64) -> StencilOperator {
        let mut rng = SplitMix64(seed);
        let views = (0..d.views_u * d.views_v)
            .map(|_| {
                let x0 = (rng.next_f64() * 14.0) as i64 - 9;
                let y0 = (rng.next_f64() * 14.0) as i64 - 9;
                let (w, h) = (1 + (rng.next_f64() * 11.0) as i64, 1 + (rng.next_f64() * 9.0) as i64);
                let mut taps = Vec::new();
                let mut dvals = Vec::new();
                for dy in y0..y0 + h {
                    for dx in x0..x0 + w {
                        let v = rng.next_f64();
                        let value = if v < 0.2 { 0.0 } else { v as f32 };
                        taps.push((dx, dy, value));
                        dvals.push([rng.next_f64() as f32 - 0.5]);
                    }
                }
                let taps: Vec<(i64, i64, f32, &[f32])> = taps
                    .iter()
                    .zip(&dvals)
                    .map(|(t, dv)| (t.0, t.1, t.2, dv.as_slice()))
                    .collect();
                ViewStencil::from_taps(&taps, 1)
            })
            .collect();
        StencilOperator::new(d, k, views)
    }

    fn random(n: usize, seed: u64) -> Vec<f32> {
        let mut rng = SplitMix64(seed);
        (0..n).map(|_| rng.next_f64() as f32 - 0.3).collect()
    }

    /// T's columns written out one by one from the kernels' definition: (x·k + dx, y·k + dy) ← K_v(dx, dy).
    fn dense(op: &StencilOperator, d: &DisplayGeometry, term: Option<usize>) -> Vec<Vec<f64>> {
        let (w, h) = ((op.holes_x * op.k) as i64, (op.holes_y * op.k) as i64);
        let mut t = vec![vec![0f64; op.n_samples()]; op.n_pixels()];
        for (p, column) in (0..op.n_samples()).map(|p| (p, d.sample_coords(p))) {
            let (x, y, i, j) = column;
            let v = &op.views[(j * d.views_u + i) as usize];
            let values = v.values(term);
            for cy in 0..v.height {
                for cx in 0..v.width {
                    let gx = x as i64 * op.k as i64 + v.x0 + cx as i64;
                    let gy = y as i64 * op.k as i64 + v.y0 + cy as i64;
                    if (0..w).contains(&gx) && (0..h).contains(&gy) {
                        t[(gy * w + gx) as usize][p] += values[cy * v.width + cx] as f64;
                    }
                }
            }
        }
        t
    }

    /// Both ways of computing the products (stencils and FFTs, `super::super::fft`) against T written out.
    #[test]
    fn the_stencil_products_equal_the_written_out_matrix_and_its_transpose() {
        let n_bands = 3;
        let c = [0.7f32, -0.2, 0.4];
        for (d, k, method) in displays().into_iter().flat_map(|d| {
            (1..=3).flat_map(move |k| [ProductMethod::Stencil, ProductMethod::Fft].map(|m| (d.clone(), k, m)))
        }) {
            let op = operator(&d, k, 11 + k as u64).with_method(method);
            assert_eq!(op.method(), method);
            for term in [None, Some(0)] {
                let t = dense(&op, &d, term);
                let l = random(op.n_samples() * n_bands, 3);
                let y = random(op.n_pixels() * 3, 4);
                // Forward, band 1, accumulated onto a non-zero image.
                let mut out = random(op.n_pixels() * 3, 5);
                let before = out.clone();
                op.forward_band(term, &l, n_bands, 1, c, true, &mut out);
                for r in 0..op.n_pixels() {
                    let s: f64 = (0..op.n_samples()).map(|p| t[r][p] * l[p * n_bands + 1] as f64).sum();
                    for a in 0..3 {
                        let want = before[r * 3 + a] as f64 + c[a] as f64 * s;
                        assert!(
                            (out[r * 3 + a] as f64 - want).abs() < 1e-4,
                            "{method:?} k {k} {term:?} forward r {r}: {} against {want}",
                            out[r * 3 + a]
                        );
                    }
                }
                // Adjoint into band 2; bands 0 and 1 untouched.
                let mut back = random(op.n_samples() * n_bands, 6);
                let kept = back.clone();
                op.adjoint_band(term, &y, n_bands, 2, c, &mut back);
                for p in 0..op.n_samples() {
                    let want: f64 = (0..op.n_pixels())
                        .map(|r| t[r][p] * (0..3).map(|a| c[a] as f64 * y[r * 3 + a] as f64).sum::<f64>())
                        .sum();
                    assert!(
                        (back[p * n_bands + 2] as f64 - want).abs() < 1e-4,
                        "{method:?} k {k} {term:?} adjoint p {p}: {} against {want}",
                        back[p * n_bands + 2]
                    );
                    assert_eq!(back[p * n_bands], kept[p * n_bands]);
                    assert_eq!(back[p * n_bands + 1], kept[p * n_bands + 1]);
                }
                if term.is_none() {
                    let nnz = t.iter().flatten().filter(|v| **v != 0.0).count();
                    assert_eq!(op.nnz(), nnz, "k {k}");
                    for p in [0, 7, op.n_samples() - 1] {
                        let col: Vec<(u32, f32)> = op.column(&d, p);
                        let want: Vec<(u32, f64)> = (0..op.n_pixels())
                            .filter(|r| t[*r][p] != 0.0)
                            .map(|r| (r as u32, t[r][p]))
                            .collect();
                        assert_eq!(col.len(), want.len());
                        for (a, b) in col.iter().zip(&want) {
                            assert_eq!(a.0, b.0);
                            assert!((a.1 as f64 - b.1).abs() < 1e-6);
                        }
                    }
                }
            }
        }
    }

    /// One light field gathered with the widest padding serves every operator's forward product, and the
    /// adjoints combined per view give the gradient of writing each out and adding the fields: bit for bit,
    /// whether an operator's products run by stencils or by FFT.
    #[test]
    fn a_shared_gather_and_combined_planes_change_no_bit() {
        let n_bands = 3;
        let cs = [[0.7f32, -0.2, 0.4], [0.1, 0.5, 0.3], [0.2, 0.2, -0.6]];
        for (d, k) in displays()
            .into_iter()
            .flat_map(|d| (1..=3).map(move |k| (d.clone(), k)))
        {
            // The second operator's products run by FFT: it reads the light field itself, and its adjoint's
            // planes are combined with the others'.
            let ops: Vec<StencilOperator> = [11u64, 29, 47]
                .iter()
                .zip([ProductMethod::Stencil, ProductMethod::Fft, ProductMethod::Stencil])
                .map(|(seed, m)| operator(&d, k, seed + k as u64).with_method(m))
                .collect();
            let pads: Vec<usize> = ops.iter().map(|o| o.gather_pad()).collect();
            let pad = *pads.iter().max().unwrap();
            assert!(pads.iter().any(|p| *p < pad), "k {k}: paddings {pads:?} all equal");
            let l = random(ops[0].n_samples() * n_bands, 3);
            let gathered = ops[0].gather(&l, n_bands, &[0, 2], pad);
            let (mu, scale) = (0.013f32, 0.77f32);
            let mut planes = Vec::new();
            let mut field_sum: Vec<f32> = l.iter().map(|x| 2.0 * mu * x).collect();
            for (op, seed) in ops.iter().zip(5..) {
                let (mut plain, mut shared) = (vec![0f32; op.n_pixels() * 3], vec![0f32; op.n_pixels() * 3]);
                for (n, c) in cs.iter().enumerate() {
                    op.forward_band(None, &l, n_bands, n, *c, n > 0, &mut plain);
                    op.forward_from(None, Some(&gathered), &l, n_bands, n, *c, n > 0, &mut shared);
                }
                assert!(plain.iter().any(|v| *v != 0.0));
                assert_eq!(plain, shared, "k {k}: forward");
                let y = random(op.n_pixels() * 3, seed);
                let mut field = vec![0f32; l.len()];
                let mut p = vec![0f32; op.plane_len() * n_bands];
                for (n, c) in cs.iter().enumerate() {
                    op.adjoint_band(None, &y, n_bands, n, *c, &mut field);
                    op.adjoint_planes(None, &y, *c, &mut p[n * op.plane_len()..(n + 1) * op.plane_len()]);
                }
                for (o, v) in field_sum.iter_mut().zip(&field) {
                    *o += scale * v;
                }
                planes.push(p);
            }
            let refs: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
            let mut combined = vec![0f32; l.len()];
            ops[0].combine_planes(&l, mu, scale, &refs, n_bands, &mut combined);
            assert_eq!(combined, field_sum, "k {k}: combined adjoints");
        }
    }

    /// Several operators' kernels on one grid per band (`SharedSpectra`) against T written out: every
    /// observer's forward product from the views transformed once, and the sum of their adjoints (plus 2μ·x)
    /// folded and transformed once; operators on different displays are refused.
    #[test]
    fn shared_grids_give_every_observer_s_product_and_the_sum_of_adjoints() {
        let n_bands = 2;
        let cs = [
            [[0.7f32, -0.2, 0.4], [0.1, 0.5, 0.3]],
            [[0.2, 0.2, -0.6], [0.9, 0.1, 0.0]],
            [[-0.3, 0.8, 0.2], [0.4, 0.4, 0.4]],
        ];
        let (mu, scale) = (0.013f32, 0.77f32);
        for (d, k) in displays()
            .into_iter()
            .flat_map(|d| (1..=3).map(move |k| (d.clone(), k)))
        {
            let ops: Vec<Vec<StencilOperator>> = (0..3u64)
                .map(|o| {
                    (0..n_bands as u64)
                        .map(|n| operator(&d, k, 100 + 10 * o + n + k as u64))
                        .collect()
                })
                .collect();
            let refs: Vec<Vec<&StencilOperator>> = ops.iter().map(|o| o.iter().collect()).collect();
            let shared = shared_spectra(&refs, false).expect("one display");
            let (samples, pixels) = (ops[0][0].n_samples(), ops[0][0].n_pixels());
            let l = random(samples * n_bands, 3);
            let mut views = ViewSpectra::default();
            shared.transform(&l, &mut views);
            let mut want_grad: Vec<f64> = l.iter().map(|x| 2.0 * mu as f64 * *x as f64).collect();
            let mut images = Vec::new();
            for (o, band_ops) in ops.iter().enumerate() {
                let t: Vec<Vec<Vec<f64>>> = band_ops.iter().map(|op| dense(op, &d, None)).collect();
                let mut out = random(pixels * 3, 9);
                shared.forward(o, &views, &cs[o], &mut out);
                for r in 0..pixels {
                    for a in 0..3 {
                        let want: f64 = (0..n_bands)
                            .map(|n| {
                                let s: f64 = (0..samples).map(|p| t[n][r][p] * l[p * n_bands + n] as f64).sum();
                                cs[o][n][a] as f64 * s
                            })
                            .sum();
                        let got = out[r * 3 + a] as f64;
                        assert!(
                            (got - want).abs() < 1e-4 * (1.0 + want.abs()),
                            "k {k} o {o} r {r}: {got} against {want}"
                        );
                    }
                }
                let y = random(pixels * 3, 20 + o as u64);
                let mut image = ImageSpectra::default();
                shared.image_spectra(&y, &cs[o], &mut image);
                images.push(image);
                for (p, n) in (0..samples).flat_map(|p| (0..n_bands).map(move |n| (p, n))) {
                    let back: f64 = (0..pixels)
                        .map(|r| t[n][r][p] * (0..3).map(|a| cs[o][n][a] as f64 * y[r * 3 + a] as f64).sum::<f64>())
                        .sum();
                    want_grad[p * n_bands + n] += scale as f64 * back;
                }
            }
            let refs: Vec<&ImageSpectra> = images.iter().collect();
            let mut grad = random(l.len(), 7);
            shared.adjoint(&refs, &l, mu, scale, &mut views, &mut grad);
            for (p, (got, want)) in grad.iter().zip(&want_grad).enumerate() {
                assert!(
                    (*got as f64 - want).abs() < 1e-4 * (1.0 + want.abs()),
                    "k {k} adjoint {p}: {got} against {want}"
                );
            }
        }
        let [a, b, _] = displays();
        let (oa, ob) = (operator(&a, 1, 1), operator(&b, 1, 2));
        assert!(shared_spectra(&[vec![&oa], vec![&ob]], false).is_none());
    }
}
