//! Light transport from the display's light field to one observer's retinal image (paper Eqs. 9–11, 13).
//!
//! The paper's T is 0/1 per ray (Eq. 10). eyekey makes it physical (docs/design.md §2): for every light-field sample
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

mod byte_cache;
mod cache;
mod csr;
mod fft;
mod grid;
mod kernels;
mod quadrature;
pub(crate) mod rng;
mod shift_invariant;
mod stencil;
mod trace;

pub use cache::{TransportCache, DEFAULT_CAPACITY_BYTES};

/// The most memory one band's traced wave-optics operator may take (T, Tᵀ and their derivative values), for
/// an eye nearer or farther than the design distance (at the design distance the operator is per-view
/// stencils of a few hundred KiB): the resolving presets need tens of MiB; unresolved pinhole displays need
/// gigabytes, which no job should claim.
pub const MAX_WAVE_OPERATOR_BYTES: usize = 256 << 20;
pub use csr::CsrMatrix;
pub(crate) use fft::{ImageSpectra, SharedSpectra, ViewSpectra};
pub use grid::{
    EyePosition, RetinalGrid, SubRaySequence, TransportOptions, WaveSampling, DEFAULT_WAVELENGTHS_PER_BAND,
};
use kernels::{spmv_band_adjoint, spmv_band_forward, spmv_fused};
pub use quadrature::deterministic_kernels;
pub use shift_invariant::{angle_sampling_radius_mm, RAY_BUNDLE_CACHE_BYTES, SAMPLING_PUPIL_STEP_MM};
pub(crate) use stencil::shared_spectra;
pub use stencil::{multiply_add_peak_gflops, vector_isa, GatheredField, ProductMethod, StencilOperator};
pub use trace::block_seen;

use rayon::prelude::*;

use crate::physics::display::DisplayGeometry;

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
    /// A wave-optics operator would need more memory than one operator may take.
    #[error(
        "under wave optics one band's transport operator for this display would take {mib} MiB (at most {limit_mib} MiB): \
         diffraction spreads every screen pixel's light through {apertures} apertures; displays whose views are \
         resolved (`eyekey display check`: M >= 1) stay small, or use optics \"geometric\""
    )]
    OverBudget {
        /// What the operator would take, MiB.
        mib: usize,
        /// The bound, MiB.
        limit_mib: usize,
        /// Apertures each sample's light passes through (the neighbour window).
        apertures: usize,
    },
}

/// One observer's light-transport operator T (Eqs. 10, 11, 13) and, optionally, ∂T/∂W_j.
#[derive(Clone)]
pub struct TransportMatrix {
    /// The retinal grid (rows of T).
    pub grid: RetinalGrid,
    /// OSA indices of the stored derivatives.
    pub derivative_terms: Vec<usize>,
    /// Statistics of the build.
    pub stats: TransportStats,
    repr: Repr,
}

impl std::fmt::Debug for TransportMatrix {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TransportMatrix")
            .field("grid", &self.grid)
            .field("derivative_terms", &self.derivative_terms)
            .field("stats", &self.stats)
            .field("stencil", &self.is_stencil())
            .field("nnz", &self.nnz())
            .field("bytes", &self.memory_bytes())
            .finish()
    }
}

/// How T is held.
#[derive(Clone)]
enum Repr {
    /// A traced T: CSR and its transpose, with ∂T/∂W_j on each pattern.
    Sparse(Sparse),
    /// The shift-invariant wave operator at the design distance: one kernel per view.
    Stencil(StencilOperator),
}

#[derive(Clone)]
struct Sparse {
    /// T: retinal pixels × light-field samples.
    forward: CsrMatrix,
    /// Tᵀ: light-field samples × retinal pixels.
    adjoint: CsrMatrix,
    /// ∂T/∂W_j values on the pattern of `forward`, one vector per term.
    derivative_forward: Vec<Vec<f32>>,
    /// The same values on the pattern of `adjoint`.
    derivative_adjoint: Vec<Vec<f32>>,
}

/// What a transport build traced.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TransportStats {
    pub sub_rays_traced: u64,
    /// Sub-rays that entered the pupil.
    pub sub_rays_in_pupil: u64,
    /// Holes that sent at least one sub-ray into the pupil.
    pub holes_seen: u64,
    /// Sub-rays that landed outside the retinal grid (lost at the image's border).
    pub sub_rays_off_grid: u64,
}

impl TransportMatrix {
    /// Σ_q w_q·T_q (and ∂T/∂W_j alike): the operator of a band whose light is a mixture of the parts'
    /// wavelengths with power fractions w_q (docs/design.md §2.7). The parts must come from the same display,
    /// eye position and options, one wavelength each.
    pub fn mix(parts: &[(f64, &TransportMatrix)]) -> Self {
        assert!(!parts.is_empty(), "at least one part");
        let first = parts[0].1;
        let mut stats = TransportStats::default();
        for (_, p) in parts {
            stats.sub_rays_traced += p.stats.sub_rays_traced;
            stats.sub_rays_in_pupil += p.stats.sub_rays_in_pupil;
            stats.sub_rays_off_grid += p.stats.sub_rays_off_grid;
            stats.holes_seen = stats.holes_seen.max(p.stats.holes_seen);
        }
        let repr = match &first.repr {
            Repr::Stencil(_) => {
                let ops: Vec<(f64, &StencilOperator)> = parts
                    .iter()
                    .map(|(w, p)| match &p.repr {
                        Repr::Stencil(st) => (*w, st),
                        Repr::Sparse(_) => panic!("mixed operators are held alike"),
                    })
                    .collect();
                Repr::Stencil(StencilOperator::mix(&ops))
            }
            Repr::Sparse(_) => {
                let mats: Vec<(f64, &Sparse)> = parts
                    .iter()
                    .map(|(w, p)| match &p.repr {
                        Repr::Sparse(m) => (*w, m),
                        Repr::Stencil(_) => panic!("mixed operators are held alike"),
                    })
                    .collect();
                let n_terms = first.derivative_terms.len();
                let n_rows = mats[0].1.adjoint.n_rows;
                // Tᵀ row by row: every part's entries of the row, merged by retinal pixel.
                let rows: Vec<Vec<(u32, f32, Vec<f32>)>> = (0..n_rows)
                    .into_par_iter()
                    .map(|r| {
                        let mut entries: Vec<(u32, f32, Vec<f32>)> = Vec::new();
                        for (w, m) in &mats {
                            let a = &m.adjoint;
                            for e in a.indptr[r] as usize..a.indptr[r + 1] as usize {
                                let dw = m.derivative_adjoint.iter().map(|d| (w * d[e] as f64) as f32).collect();
                                entries.push((a.indices[e], (w * a.values[e] as f64) as f32, dw));
                            }
                        }
                        entries.sort_by_key(|e| e.0);
                        let mut merged: Vec<(u32, f32, Vec<f32>)> = Vec::with_capacity(entries.len());
                        for e in entries {
                            match merged.last_mut() {
                                Some(last) if last.0 == e.0 => {
                                    last.1 += e.1;
                                    last.2.iter_mut().zip(&e.2).for_each(|(a, b)| *a += b);
                                }
                                _ => merged.push(e),
                            }
                        }
                        merged
                    })
                    .collect();
                let mut indptr = Vec::with_capacity(n_rows + 1);
                let (mut indices, mut values) = (Vec::new(), Vec::new());
                let mut dvalues: Vec<Vec<f32>> = vec![Vec::new(); n_terms];
                indptr.push(0u32);
                for row in rows {
                    for (c, v, dv) in row {
                        indices.push(c);
                        values.push(v);
                        for (d, x) in dvalues.iter_mut().zip(dv) {
                            d.push(x);
                        }
                    }
                    indptr.push(indices.len() as u32);
                }
                let adjoint = CsrMatrix {
                    n_rows,
                    n_cols: mats[0].1.adjoint.n_cols,
                    indptr,
                    indices,
                    values,
                };
                return trace::finish(first.grid, adjoint, dvalues, first.derivative_terms.clone(), stats);
            }
        };
        TransportMatrix {
            grid: first.grid,
            derivative_terms: first.derivative_terms.clone(),
            stats,
            repr,
        }
    }

    /// Light-field samples per band (columns of T).
    pub fn n_samples(&self) -> usize {
        match &self.repr {
            Repr::Sparse(m) => m.forward.n_cols,
            Repr::Stencil(st) => st.n_samples(),
        }
    }

    /// Retinal pixels (rows of T).
    pub fn n_pixels(&self) -> usize {
        self.grid.len()
    }

    /// Non-zero entries of T (for a stencil operator: the multiply-adds of one product).
    pub fn nnz(&self) -> usize {
        match &self.repr {
            Repr::Sparse(m) => m.forward.nnz(),
            Repr::Stencil(st) => st.nnz(),
        }
    }

    /// Bytes held by the operator.
    pub fn memory_bytes(&self) -> usize {
        match &self.repr {
            Repr::Sparse(m) => {
                let csr = |c: &CsrMatrix| c.indptr.len() * 4 + c.indices.len() * 4 + c.values.len() * 4;
                csr(&m.forward)
                    + csr(&m.adjoint)
                    + 4 * m
                        .derivative_forward
                        .iter()
                        .chain(&m.derivative_adjoint)
                        .map(Vec::len)
                        .sum::<usize>()
            }
            Repr::Stencil(st) => st.memory_bytes(),
        }
    }

    /// T and Tᵀ as CSR, for an operator that is held that way (a traced T; not the stencils of the
    /// shift-invariant wave operator).
    pub fn sparse(&self) -> Option<(&CsrMatrix, &CsrMatrix)> {
        match &self.repr {
            Repr::Sparse(m) => Some((&m.forward, &m.adjoint)),
            Repr::Stencil(_) => None,
        }
    }

    /// True when T is held as per-view stencils.
    pub fn is_stencil(&self) -> bool {
        self.stencil().is_some()
    }

    /// The per-view operator, when T is held so.
    pub fn stencil(&self) -> Option<&StencilOperator> {
        match &self.repr {
            Repr::Sparse(_) => None,
            Repr::Stencil(st) => Some(st),
        }
    }

    /// How a per-view (stencil-held) operator computes its products; `None` for a traced CSR operator.
    pub fn product_method(&self) -> Option<ProductMethod> {
        self.stencil().map(StencilOperator::method)
    }

    /// The same operator with a per-view operator's products computed by `method` (a CSR operator is
    /// returned as it is).
    pub fn with_product_method(&self, method: ProductMethod) -> Self {
        let mut t = self.clone();
        if let Repr::Stencil(st) = &self.repr {
            t.repr = Repr::Stencil(st.with_method(method));
        }
        t
    }

    /// Light-field sample `p`'s retinal pixels and weights: T's column p.
    pub fn column(&self, display: &DisplayGeometry, p: usize) -> Vec<(u32, f32)> {
        match &self.repr {
            Repr::Sparse(m) => {
                let (a, b) = (m.adjoint.indptr[p] as usize, m.adjoint.indptr[p + 1] as usize);
                m.adjoint.indices[a..b]
                    .iter()
                    .copied()
                    .zip(m.adjoint.values[a..b].iter().copied())
                    .collect()
            }
            Repr::Stencil(st) => st.column(display, p),
        }
    }

    /// S = (C ⊗ T)·L (Eq. 13): `l[p·N + n]` → `out[r·3 + a]`. `coupling[n][a]` = c_na.
    pub fn forward_lms(&self, l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.forward_with(None, l, coupling, out);
    }

    /// Lᵀ-side adjoint: `y[r·3 + a]` → `out[p·N + n]` = Σ_a c_na (Tᵀ y_a)_p.
    pub fn adjoint_lms(&self, y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.adjoint_with(None, y, coupling, out);
    }

    /// (C ⊗ ∂T/∂W_j)·L for the k-th stored derivative term.
    pub fn derivative_forward_lms(&self, k: usize, l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.forward_with(Some(k), l, coupling, out);
    }

    /// Adjoint of [`Self::derivative_forward_lms`].
    pub fn derivative_adjoint_lms(&self, k: usize, y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        self.adjoint_with(Some(k), y, coupling, out);
    }

    /// One band n of S = Σ_n c_n ⊗ T_n L_n, for an operator that is band n's own (wave optics): `out[r·3 + a]`
    /// (+)= c[a] (T L_n)_r over the N-band light field `l`; `term` selects ∂T/∂W_term instead of T, and with
    /// `accumulate` the band is added to `out`.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_band_lms(
        &self,
        term: Option<usize>,
        l: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        accumulate: bool,
        out: &mut [f32],
    ) {
        assert_eq!(l.len(), self.n_samples() * n_bands, "light field length");
        assert_eq!(out.len(), self.n_pixels() * 3, "retinal image length");
        match &self.repr {
            Repr::Sparse(m) => {
                let values = term.map_or(&m.forward.values, |k| &m.derivative_forward[k]);
                let f = &m.forward;
                spmv_band_forward(&f.indptr, &f.indices, values, l, n_bands, band, c, accumulate, out);
            }
            Repr::Stencil(st) => st.forward_band(term, l, n_bands, band, c, accumulate, out),
        }
    }

    /// The adjoint of [`Self::forward_band_lms`]: `out[p·N + band]` = Σ_a c[a] (Tᵀ y_a)_p; other bands'
    /// entries are left as they are.
    pub fn adjoint_band_lms(
        &self,
        term: Option<usize>,
        y: &[f32],
        n_bands: usize,
        band: usize,
        c: [f32; 3],
        out: &mut [f32],
    ) {
        assert_eq!(y.len(), self.n_pixels() * 3, "retinal image length");
        assert_eq!(out.len(), self.n_samples() * n_bands, "light field length");
        match &self.repr {
            Repr::Sparse(m) => {
                let values = term.map_or(&m.adjoint.values, |k| &m.derivative_adjoint[k]);
                let a = &m.adjoint;
                spmv_band_adjoint(&a.indptr, &a.indices, values, y, c, n_bands, band, out);
            }
            Repr::Stencil(st) => st.adjoint_band(term, y, n_bands, band, c, out),
        }
    }

    fn forward_with(&self, term: Option<usize>, l: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        let n = coupling.len();
        assert_eq!(l.len(), self.n_samples() * n, "light field length");
        assert_eq!(out.len(), self.n_pixels() * 3, "retinal image length");
        match &self.repr {
            Repr::Sparse(m) => {
                let values = term.map_or(&m.forward.values, |k| &m.derivative_forward[k]);
                let f = &m.forward;
                spmv_fused(&f.indptr, &f.indices, values, l, n, coupling, false, out, 3);
            }
            Repr::Stencil(st) => {
                for (band, c) in coupling.iter().enumerate() {
                    st.forward_band(term, l, n, band, *c, band > 0, out);
                }
            }
        }
    }

    fn adjoint_with(&self, term: Option<usize>, y: &[f32], coupling: &[[f32; 3]], out: &mut [f32]) {
        let n = coupling.len();
        assert_eq!(y.len(), self.n_pixels() * 3, "retinal image length");
        assert_eq!(out.len(), self.n_samples() * n, "light field length");
        match &self.repr {
            Repr::Sparse(m) => {
                let values = term.map_or(&m.adjoint.values, |k| &m.derivative_adjoint[k]);
                let a = &m.adjoint;
                spmv_fused(&a.indptr, &a.indices, values, y, 3, coupling, true, out, n);
            }
            Repr::Stencil(st) => {
                for (band, c) in coupling.iter().enumerate() {
                    st.adjoint_band(term, y, n, band, *c, out);
                }
            }
        }
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
    use crate::physics::display::Aperture;

    use crate::physics::display::DisplayGeometry;
    use crate::physics::zernike::Prescription;
    use crate::physics::zernike::ZernikeCoefficients;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_fast_floor_is_the_floor() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            -0.5,
            1e-300,
            -1e-300,
            2.0_f64.powi(52) + 0.5,
            -7.999999999,
        ];
        for x in special.into_iter().chain((0..10_000).map(|_| rng.gen_range(-1e6..1e6))) {
            assert_eq!(trace::floor(x), x.floor(), "{x}");
        }
    }

    fn tiny() -> DisplayGeometry {
        DisplayGeometry {
            aperture: Default::default(),
            holes_x: 16,
            holes_y: 12,
            ..DisplayGeometry::paper()
        }
    }

    /// `tiny` with lenslets filling their pitch.
    fn tiny_lenslet() -> DisplayGeometry {
        let mut lenslet = tiny();
        lenslet.aperture = Aperture::Lenslet;
        lenslet.hole_diameter_mm = lenslet.hole_pitch_mm;
        lenslet
    }

    /// An eye 2 mm to the right of the design position.
    fn two_mm_aside() -> EyePosition {
        EyePosition {
            x_mm: 2.0,
            ..Default::default()
        }
    }

    /// The LMS values of the retinal pixels at least two apertures from the edge of `d`.
    fn interior(d: &DisplayGeometry, y: &[f32]) -> Vec<f64> {
        let mut v = Vec::new();
        for yy in 2..d.holes_y - 2 {
            for x in 2..d.holes_x - 2 {
                v.extend((0..3).map(|ch| y[((yy * d.holes_x + x) * 3 + ch) as usize] as f64));
            }
        }
        v
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
        // ⟨A L, y⟩ = ⟨L, Aᵀ y⟩ for random L, y; f32 accumulation: relative 1e-5. Under wave optics too, from an
        // eye 10 mm aside, where neighbouring blocks' light enters the pupil.
        let eye = EyePosition {
            x_mm: 10.0,
            y_mm: 0.0,
            dz_mm: 20.0,
        };
        let wave = Some(WaveSampling {
            wavelength_nm: 450.0,
            neighbour_blocks: 1,
            kernel_rays: 0,
        });
        // And with the shift-invariant kernels, from an eye 3 mm aside at the design distance.
        let aside = EyePosition {
            x_mm: 3.0,
            ..Default::default()
        };
        let kernels = wave.map(|w| WaveSampling { kernel_rays: 256, ..w });
        for (eye, wave) in [(EyePosition::default(), None), (eye, wave), (aside, kernels)] {
            check_adjoint(eye, wave);
        }
    }

    fn check_adjoint(eye: EyePosition, wave: Option<WaveSampling>) {
        let d = tiny();
        let opts = TransportOptions {
            derivative_terms: vec![4, 7],
            wave,
            ..Default::default()
        };
        let t = TransportMatrix::build(&d, &aberrated(6.0), eye, &opts).unwrap();
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

    /// The single-band plain image of `value` seen through `t` (channel L, row-major per hole).
    fn plain_view(d: &DisplayGeometry, t: &TransportMatrix, value: f32) -> Vec<f32> {
        let d1 = DisplayGeometry {
            projectors: d.projectors[..1].to_vec(),
            ..d.clone()
        };
        let ones = vec![value; (d.holes_x * d.holes_y) as usize];
        let mut out = vec![0f32; t.n_pixels() * 3];
        t.forward_lms(&plain_light_field(&d1, &ones), &[[1.0, 0.0, 0.0]], &mut out);
        out.chunks_exact(3).map(|p| p[0]).collect()
    }

    fn wave(lambda: f64, neighbour_blocks: u32) -> TransportOptions {
        TransportOptions {
            sub_rays: 64,
            wave: Some(WaveSampling {
                wavelength_nm: lambda,
                neighbour_blocks,
                kernel_rays: 0,
            }),
            ..Default::default()
        }
    }

    #[test]
    fn a_mixed_operator_is_the_weighted_sum_of_its_parts_held_either_way() {
        // Two wavelengths' operators, mixed 0.3/0.7: every product (T and ∂T/∂W) equals the same mixture of the
        // parts' products, for the stencils (design distance) and for traced CSR (an eye 40 mm nearer).
        let d = tiny();
        for (eye, kernel_rays) in [
            (EyePosition::default(), 512),
            (
                EyePosition {
                    dz_mm: -40.0,
                    ..Default::default()
                },
                0,
            ),
        ] {
            let part = |lambda: f64| {
                let opts = TransportOptions {
                    sub_rays: 8,
                    derivative_terms: vec![4],
                    wave: Some(WaveSampling {
                        wavelength_nm: lambda,
                        neighbour_blocks: 1,
                        kernel_rays,
                    }),
                    ..Default::default()
                };
                TransportMatrix::build(&d, &aberrated(6.0), eye, &opts).unwrap()
            };
            let (a, b) = (part(450.0), part(480.0));
            assert_eq!(a.is_stencil(), kernel_rays > 0);
            let m = TransportMatrix::mix(&[(0.3, &a), (0.7, &b)]);
            assert_eq!(m.is_stencil(), a.is_stencil());
            let c = coupling4();
            let l = rand_vec(a.n_samples() * 4, 3);
            let y = rand_vec(a.n_pixels() * 3, 4);
            for term in [None, Some(0)] {
                let forward = |t: &TransportMatrix| {
                    let mut out = vec![0f32; t.n_pixels() * 3];
                    match term {
                        None => t.forward_lms(&l, &c, &mut out),
                        Some(k) => t.derivative_forward_lms(k, &l, &c, &mut out),
                    }
                    out
                };
                let adjoint = |t: &TransportMatrix| {
                    let mut out = vec![0f32; t.n_samples() * 4];
                    match term {
                        None => t.adjoint_lms(&y, &c, &mut out),
                        Some(k) => t.derivative_adjoint_lms(k, &y, &c, &mut out),
                    }
                    out
                };
                for (got, pa, pb) in [
                    (forward(&m), forward(&a), forward(&b)),
                    (adjoint(&m), adjoint(&a), adjoint(&b)),
                ] {
                    let scale = got.iter().fold(0f32, |s, v| s.max(v.abs())).max(1e-6);
                    for ((g, x), z) in got.iter().zip(&pa).zip(&pb) {
                        let want = 0.3 * x + 0.7 * z;
                        assert!((g - want).abs() <= 1e-5 * scale, "{eye:?} {term:?}: {g} vs {want}");
                    }
                }
            }
        }
    }

    #[test]
    fn under_wave_optics_a_perfect_eye_sees_a_plain_image_at_its_own_brightness_on_both_kinds() {
        // Brightness is normalised once, by the mean light that 25 apertures spread over the barrier send into
        // the pupil from the design position, so an interior aperture, whose fan is aimed at the same eye, is
        // seen at the image's value within the Monte-Carlo noise of 64 sub-rays × 25 views × 9 blocks, of which
        // about a third enter the pupil (1.6 % relative standard deviation: 6 % is four of them). The
        // shift-invariant kernels (4096 sub-rays per view and block) have no per-aperture noise at all.
        let lenslet = tiny_lenslet();
        let kernels = TransportOptions {
            wave: wave(550.0, 1).wave.map(|w| WaveSampling { kernel_rays: 4096, ..w }),
            ..wave(550.0, 1)
        };
        for (d, opts) in [(tiny(), wave(550.0, 1)), (lenslet, wave(550.0, 1)), (tiny(), kernels)] {
            let t = TransportMatrix::build(&d, &ZernikeCoefficients::zero(6.0), EyePosition::default(), &opts).unwrap();
            let seen = plain_view(&d, &t, 0.7);
            let mut interior = Vec::new();
            for y in 2..d.holes_y - 2 {
                for x in 2..d.holes_x - 2 {
                    let v = seen[(y * d.holes_x + x) as usize];
                    assert!((v - 0.7).abs() < 0.042, "{:?} ({x},{y}): {v}", d.aperture);
                    interior.push(v);
                }
            }
            let mean = interior.iter().sum::<f32>() / interior.len() as f32;
            assert!((mean - 0.7).abs() < 0.014, "{:?} mean {mean}", d.aperture);
        }
    }

    #[test]
    fn an_eye_30_mm_to_the_side_sees_light_through_neighbouring_blocks() {
        // 30 mm off axis is five view fans away (one block's light lands p_h(1 + g/d)·d/g = 6.05 mm over). The
        // geometric model traces each hole's own block only, so this eye sees nothing; the wave model traces
        // the blocks that point at it and sees the plain image, dimmer where fewer rays enter, but lit.
        let d = tiny();
        let eye = EyePosition {
            x_mm: 30.0,
            y_mm: 0.0,
            dz_mm: 0.0,
        };
        let w0 = ZernikeCoefficients::zero(6.0);
        let geometric = TransportMatrix::build(&d, &w0, eye, &Default::default()).unwrap();
        assert_eq!(geometric.stats.sub_rays_in_pupil, 0);
        let t = TransportMatrix::build(&d, &w0, eye, &wave(550.0, 1)).unwrap();
        assert!(t.stats.sub_rays_in_pupil > 0);
        let seen = plain_view(&d, &t, 1.0);
        // The columns whose neighbours five blocks over exist (x < X − 5) are lit; the light is the light
        // that enters the pupil, not a normalised copy of the design view.
        let lit: Vec<f32> = (2..d.holes_y - 2)
            .flat_map(|y| (2..d.holes_x - 7).map(move |x| (y * d.holes_x + x) as usize))
            .map(|h| seen[h])
            .collect();
        let mean = lit.iter().sum::<f32>() / lit.len() as f32;
        assert!(mean > 0.3 && mean < 1.5, "mean brightness {mean}");
    }

    #[test]
    fn the_block_an_eye_sees_is_the_one_its_chief_ray_lands_in() {
        // Independent of block_seen's closed form: intersect the chief ray from the eye through the hole's
        // centre with the screen (q = h + (h − e)·g/d') and find the block whose extent contains q by search.
        let d = DisplayGeometry::lenslet();
        let block_pitch = d.hole_pitch_mm * (1.0 + d.gap_mm / d.viewing_distance_mm);
        for (ex, ey, d_eye) in [
            (0.0, 0.0, 500.0),
            (30.0, -12.0, 500.0),
            (-80.0, 5.0, 300.0),
            (15.0, 40.0, 1500.0),
        ] {
            for (hx, hy) in [(0, 0), (10, 30), (47, 47), (24, 3)] {
                let h = d.hole_centre_mm(hx, hy);
                let k = block_seen(&d, d_eye, [ex, ey], h);
                let q = [
                    h[0] + (h[0] - ex) * d.gap_mm / d_eye,
                    h[1] + (h[1] - ey) * d.gap_mm / d_eye,
                ];
                let found = |axis: usize, own: u32, n: u32| -> i64 {
                    (-200i64..200)
                        .find(|b| {
                            let idx = own as i64 + b;
                            let c = (idx as f64 - (n as f64 - 1.0) / 2.0) * block_pitch;
                            (q[axis] - c).abs() <= 0.5 * block_pitch
                        })
                        .unwrap()
                };
                assert_eq!(
                    k,
                    [found(0, hx, d.holes_x), found(1, hy, d.holes_y)],
                    "eye ({ex}, {ey}) at {d_eye} mm, hole ({hx}, {hy})"
                );
            }
        }
        // At the design distance every hole shows the same block offset, −e/(block shift at the pupil).
        let e = 30.0;
        let k = (-e / d.block_shift_at_pupil_mm(d.viewing_distance_mm)).round() as i64;
        for hx in [0, 20, 47] {
            let h = d.hole_centre_mm(hx, 5);
            assert_eq!(block_seen(&d, d.viewing_distance_mm, [e, 0.0], h)[0], k);
        }
    }

    #[test]
    fn with_vanishing_wavelength_and_no_neighbours_the_wave_model_is_the_geometric_one() {
        // λ → 0 removes diffraction and 0 neighbour blocks the leaked light; what remains is the geometric
        // tracer with a different jitter sequence and one brightness constant instead of one per hole. At the
        // design position every fan is aimed at the eye, so the two see an aberrated plain image alike (Monte-
        // Carlo noise of 1600 sub-rays per hole: 1.2 % for the wave model's, 4 % is three of them).
        let d = tiny();
        let w = aberrated(6.0);
        let dense = TransportOptions {
            sub_rays: 64,
            ..Default::default()
        };
        let g = TransportMatrix::build(&d, &w, EyePosition::default(), &dense).unwrap();
        let t = TransportMatrix::build(&d, &w, EyePosition::default(), &wave(1e-6, 0)).unwrap();
        let (a, b) = (plain_view(&d, &g, 0.5), plain_view(&d, &t, 0.5));
        for y in 2..d.holes_y - 2 {
            for x in 2..d.holes_x - 2 {
                let h = (y * d.holes_x + x) as usize;
                assert!((a[h] - b[h]).abs() < 0.02, "({x},{y}): {} vs {}", a[h], b[h]);
            }
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
            aperture: Default::default(),
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
        check_derivative(tiny(), None, SubRaySequence::Kronecker);
    }

    #[test]
    fn under_wave_optics_the_derivative_matches_finite_differences() {
        // The same check with diffraction and neighbouring blocks: which sub-rays enter the pupil does not
        // depend on W, and the brightness constant is counted at the design pupil, so T stays piecewise
        // linear in W and the same 2 % holds.
        check_derivative(
            tiny(),
            Some(WaveSampling {
                wavelength_nm: 550.0,
                neighbour_blocks: 1,
                kernel_rays: 0,
            }),
            SubRaySequence::Kronecker,
        );
    }

    #[test]
    fn with_shift_invariant_kernels_the_derivative_matches_finite_differences() {
        // The kernels' sub-rays are fixed by the seed as the per-sample trace's are: the same argument, 2 %.
        check_derivative(
            tiny(),
            Some(WaveSampling {
                wavelength_nm: 550.0,
                neighbour_blocks: 1,
                kernel_rays: 512,
            }),
            SubRaySequence::Kronecker,
        );
    }

    #[test]
    fn with_quadrature_kernels_the_derivative_matches_finite_differences() {
        // Lenslet kernels by quadrature: every deposit is bilinear in the table, so T is piecewise
        // linear in W, and ∂T/∂W is the derivative of that interpolation: the same 2 %.
        check_derivative(
            tiny_lenslet(),
            Some(WaveSampling {
                wavelength_nm: 550.0,
                neighbour_blocks: 1,
                kernel_rays: 512,
            }),
            SubRaySequence::Quadrature,
        );
    }

    /// The view of a random light field by `w` at `eye` through kernels by quadrature and through sampled ones
    /// at a job's 682 sub-rays, each against the mean of two Kronecker builds of 65,536 sub-rays per view and block
    /// (its own error about 0.01 %), relative to the reference's contrast (RMS about its mean): (quadrature's
    /// error, sampled's error, the quadrature's view).
    fn against_converged(d: &DisplayGeometry, w: &ZernikeCoefficients, eye: EyePosition) -> (f64, f64, Vec<f64>) {
        let contrast_rms = |a: &[f64], r: &[f64]| {
            let mean = r.iter().sum::<f64>() / r.len() as f64;
            let e: f64 = a.iter().zip(r).map(|(x, y)| (x - y).powi(2)).sum();
            let n: f64 = r.iter().map(|y| (y - mean).powi(2)).sum();
            (e / n).sqrt()
        };
        let a = kernel_view_of(d, w, eye, 65_536, 98, SubRaySequence::Kronecker);
        let b = kernel_view_of(d, w, eye, 65_536, 99, SubRaySequence::Kronecker);
        let reference: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
        let quadrature = kernel_view_of(d, w, eye, 682, 1, SubRaySequence::Quadrature);
        let sampled = kernel_view_of(d, w, eye, 682, 1, SubRaySequence::Kronecker);
        (
            contrast_rms(&quadrature, &reference),
            contrast_rms(&sampled, &reference),
            quadrature,
        )
    }

    #[test]
    fn quadrature_kernels_carry_no_sampling_noise_and_are_the_converged_kernels() {
        // An aberrated 6 mm eye on lenslets at the seat and 2 mm aside ([`against_converged`]). Measured:
        // quadrature 0.030 % and 0.042 %, the sampled kernels 0.24 % and 0.31 %. Builds under other seeds are
        // the same bit for bit, and ⟨T·L, y⟩ = ⟨L, Tᵀ·y⟩.
        let d = tiny_lenslet();
        for eye in [EyePosition::default(), two_mm_aside()] {
            let (q, m, quadrature) = against_converged(&d, &aberrated(6.0), eye);
            assert!(q < 1e-3, "{eye:?}: quadrature {q}");
            assert!(m > 4.0 * q, "{eye:?}: sampled {m} against quadrature {q}");
            assert_eq!(
                quadrature,
                kernel_view(&d, eye, 682, 12_345, SubRaySequence::Quadrature)
            );
        }
        let opts = TransportOptions {
            wave: wave(640.0, 1).wave.map(|w| WaveSampling { kernel_rays: 682, ..w }),
            sequence: SubRaySequence::Quadrature,
            ..wave(640.0, 1)
        };
        let t = TransportMatrix::build(&d, &aberrated(6.0), two_mm_aside(), &opts).unwrap();
        assert!(t.is_stencil());
        let l = rand_vec(t.n_samples() * 4, 8);
        let y = rand_vec(t.n_pixels() * 3, 9);
        let (mut tl, mut ty) = (vec![0f32; t.n_pixels() * 3], vec![0f32; t.n_samples() * 4]);
        t.forward_lms(&l, &coupling4(), &mut tl);
        t.adjoint_lms(&y, &coupling4(), &mut ty);
        let (lhs, rhs) = (dot(&tl, &y), dot(&l, &ty));
        assert!((lhs - rhs).abs() <= 1e-5 * lhs.abs(), "{lhs} {rhs}");
    }

    #[test]
    fn quadrature_kernels_follow_a_landing_that_moves_fast_across_the_pupil() {
        // The aberrated 6 mm eye refocused by 2 D (c₂⁰ 0.4 + 2.6 µm), with astigmatism at 45° and 0°: the landing
        // moves up to 6 retinal pixels per mm of pupil along the axes (4 px across a cell of b on tiny_lenslet) and
        // 1.3 across them. The quadrature follows the first with points across each cell and the second by halving
        // the cells ([`against_converged`]). Measured: quadrature 0.067 % and 0.075 %, sampled at 682 sub-rays
        // 0.74 % and 0.89 %.
        let d = tiny_lenslet();
        let mut c = vec![0.0; 28];
        (c[3], c[4], c[5], c[6], c[7], c[8], c[12]) = (0.3, 3.0, -0.2, 0.08, 0.15, -0.1, 0.12);
        let w = ZernikeCoefficients::new(6.0, c).unwrap();
        for eye in [EyePosition::default(), two_mm_aside()] {
            let (q, m, _) = against_converged(&d, &w, eye);
            assert!(q < 1e-3, "{eye:?}: quadrature {q}");
            assert!(m > 4.0 * q, "{eye:?}: sampled {m} against quadrature {q}");
        }
    }

    #[test]
    fn the_shift_invariant_kernels_agree_with_the_per_sample_trace() {
        // Two independent Monte-Carlo estimates of the same operator: the per-sample trace (every sample its
        // own 256 sub-rays through 3×3 blocks) and one kernel per view (8192 sub-rays per view and block),
        // at the design position and 2 mm aside, on both aperture kinds. Their products with a random light
        // field differ by the trace's noise: each retinal pixel collects about 25 views × 9 blocks × 256
        // sub-rays × the in-pupil fraction (≥ 0.1) ≈ 6000 landings, 1.3 % relative, over interior pixels.
        // The brightness constants differ too (25 sampled apertures against the exact kernel sum, < 1 %).
        // 4 % is three standard deviations of both together.
        let lenslet = tiny_lenslet();
        let aside = two_mm_aside();
        for d in [tiny(), lenslet] {
            for eye in [EyePosition::default(), aside] {
                let traced = TransportOptions {
                    sub_rays: 256,
                    ..wave(550.0, 1)
                };
                let kernels = TransportOptions {
                    wave: traced.wave.map(|w| WaveSampling { kernel_rays: 8192, ..w }),
                    ..traced.clone()
                };
                let w = aberrated(6.0);
                let a = TransportMatrix::build(&d, &w, eye, &traced).unwrap();
                let b = TransportMatrix::build(&d, &w, eye, &kernels).unwrap();
                let c = coupling4();
                let l = rand_vec(a.n_samples() * 4, 5);
                let (mut ya, mut yb) = (vec![0f32; a.n_pixels() * 3], vec![0f32; a.n_pixels() * 3]);
                a.forward_lms(&l, &c, &mut ya);
                b.forward_lms(&l, &c, &mut yb);
                let rel = rel_rms(&interior(&d, &yb), &interior(&d, &ya));
                assert!(rel < 0.04, "{:?} eye {:?}: relative difference {rel}", d.aperture, eye);
            }
        }
    }

    /// Relative RMS difference of `a` from `reference`.
    fn rel_rms(a: &[f64], reference: &[f64]) -> f64 {
        let e: f64 = a.iter().zip(reference).map(|(x, y)| (x - y).powi(2)).sum();
        let n: f64 = reference.iter().map(|y| y * y).sum();
        (e / n).sqrt()
    }

    /// The interior of the retinal image of `d` through kernels of `rays` sub-rays drawn from `sequence` with
    /// `seed`, for a fixed random light field.
    fn kernel_view(d: &DisplayGeometry, eye: EyePosition, rays: u32, seed: u64, sequence: SubRaySequence) -> Vec<f64> {
        kernel_view_of(d, &aberrated(6.0), eye, rays, seed, sequence)
    }

    /// [`kernel_view`] through the eye `w`.
    fn kernel_view_of(
        d: &DisplayGeometry,
        w: &ZernikeCoefficients,
        eye: EyePosition,
        rays: u32,
        seed: u64,
        sequence: SubRaySequence,
    ) -> Vec<f64> {
        let opts = TransportOptions {
            seed,
            sequence,
            wave: wave(550.0, 1).wave.map(|w| WaveSampling { kernel_rays: rays, ..w }),
            ..wave(550.0, 1)
        };
        let t = TransportMatrix::build(d, w, eye, &opts).unwrap();
        let l = rand_vec(t.n_samples() * 4, 5);
        let mut y = vec![0f32; t.n_pixels() * 3];
        t.forward_lms(&l, &coupling4(), &mut y);
        interior(d, &y)
    }

    #[test]
    fn kronecker_kernels_are_unbiased_and_less_noisy_than_independent_draws() {
        // Against a reference of 2 × 65,536 independent sub-rays per view and block (its own error about 0.01 %),
        // on both sampling paths (the pinhole's pupil-sampled kernels, the lenslet's angle-sampled ones) 2 mm
        // aside: the Kronecker kernels of 256 sub-rays are closer to it than independent draws' (measured 0.16 %
        // against 0.33 % and 0.32 % against 0.75 %; BENCHMARKS.md "Kernel sampling"), and the mean of six
        // rotations is closer than one (each rotation is an independent unbiased estimate, so the mean is up to
        // √6 closer, less the reference's own error: measured 0.36× and 0.53×; a biased or unrotated sequence
        // does not come closer: 1.0×).
        let lenslet = tiny_lenslet();
        let aside = two_mm_aside();
        for d in [tiny(), lenslet] {
            let reference: Vec<f64> = {
                let a = kernel_view(&d, aside, 65_536, 98, SubRaySequence::Independent);
                let b = kernel_view(&d, aside, 65_536, 99, SubRaySequence::Independent);
                a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect()
            };
            let error = |sequence: SubRaySequence| {
                let views: Vec<Vec<f64>> = (1..=6).map(|s| kernel_view(&d, aside, 256, s, sequence)).collect();
                let single = (views.iter().map(|v| rel_rms(v, &reference).powi(2)).sum::<f64>() / 6.0).sqrt();
                let mean: Vec<f64> = (0..reference.len())
                    .map(|i| views.iter().map(|v| v[i]).sum::<f64>() / 6.0)
                    .collect();
                (single, rel_rms(&mean, &reference))
            };
            let (kronecker, kronecker_mean) = error(SubRaySequence::Kronecker);
            let (independent, _) = error(SubRaySequence::Independent);
            assert!(
                kronecker < 0.8 * independent,
                "{:?}: Kronecker {kronecker} against independent {independent}",
                d.aperture
            );
            assert!(
                kronecker_mean < 0.75 * kronecker,
                "{:?}: the mean of six rotations {kronecker_mean} against one {kronecker}",
                d.aperture
            );
        }
    }

    fn check_derivative(d: DisplayGeometry, wave: Option<WaveSampling>, sequence: SubRaySequence) {
        let base = aberrated(6.0);
        let terms = vec![4, 5, 7, 12];
        let opts = TransportOptions {
            derivative_terms: terms.clone(),
            wave,
            sequence,
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
            let plain = TransportOptions {
                wave,
                sequence,
                ..Default::default()
            };
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
