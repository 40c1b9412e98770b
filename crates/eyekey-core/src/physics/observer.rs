//! An observer of the display: one person (or camera) at one eye position, with their transport operator and
//! their spectral coupling (Eq. 13: S_a = Σ_n c_na T L_n).

use std::sync::Arc;

use image::RgbImage;

use crate::imaging;
use crate::physics::display::DisplayGeometry;
use crate::physics::profile::{ProfileError, VisionProfile};
use crate::physics::spectral::{coupling, ConeFundamentals};
use crate::physics::transport::{
    EyePosition, GatheredField, RetinalGrid, StencilOperator, TransportCache, TransportError, TransportMatrix,
    TransportOptions, WaveSampling,
};
use crate::physics::zernike::ZernikeCoefficients;

/// Errors building an observer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ObserverError {
    /// The profile is invalid.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// The transport build failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
}

/// One observer: transport operators plus spectral coupling.
///
/// Under geometric optics one operator serves every band (Eq. 13: S_a = Σ_n c_na T L_n); under wave optics each
/// band n has its own T_n (its wavelength's diffraction and the eye's chromatic defocus), S_a = Σ_n c_na T_n L_n.
#[derive(Clone, Debug)]
pub struct Observer {
    /// Transport from the light field to this observer's retinal grid: one for all bands, or one per band.
    pub transports: Vec<Arc<TransportMatrix>>,
    /// c_na per band n, as f32 for the kernels.
    pub coupling: Vec<[f32; 3]>,
    /// c_na per band n.
    pub coupling_f64: Vec<[f64; 3]>,
    /// The LMS of the display's white (every projector at L_max) for this observer.
    pub white: [f64; 3],
}

impl Observer {
    /// Builds the observer for `profile` at `eye` under `optics`, taking its transport operators from `cache`
    /// (built and stored there if absent).
    pub fn new(
        display: &DisplayGeometry,
        profile: &VisionProfile,
        eye: EyePosition,
        options: &TransportOptions,
        optics: Optics,
        cache: &TransportCache,
    ) -> Result<Self, ObserverError> {
        profile.validate()?;
        let wavefront = profile.effective_wavefront()?;
        let lens = Lens::Eye {
            wavefront: &wavefront,
            reference_nm: profile.reference_wavelength(),
        };
        Self::from_parts(display, lens, &profile.cone_fundamentals(), eye, options, optics, cache)
    }

    /// Builds an observer from its optics at the viewing pupil and its spectral sensitivities.
    #[allow(clippy::too_many_arguments)]
    pub fn from_parts(
        display: &DisplayGeometry,
        lens: Lens<'_>,
        cones: &ConeFundamentals,
        eye: EyePosition,
        options: &TransportOptions,
        optics: Optics,
        cache: &TransportCache,
    ) -> Result<Self, ObserverError> {
        let transports = transports(display, lens, eye, options, optics, cache)?;
        let c = coupling(&display.projectors, cones);
        Ok(Self::with_coupling(transports, c.c, display.l_max))
    }

    /// An observer from its transport operators (one, or one per band) and a coupling matrix.
    pub fn with_coupling(transports: Vec<Arc<TransportMatrix>>, coupling_f64: Vec<[f64; 3]>, l_max: f64) -> Self {
        assert!(
            transports.len() == 1 || transports.len() == coupling_f64.len(),
            "one transport, or one per band"
        );
        let white = std::array::from_fn(|a| coupling_f64.iter().map(|c| c[a]).sum::<f64>() * l_max);
        let coupling = coupling_f64
            .iter()
            .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
            .collect();
        Self {
            transports,
            coupling,
            coupling_f64,
            white,
        }
    }

    /// The retinal grid (every band's operator shares it).
    pub fn grid(&self) -> RetinalGrid {
        self.transports[0].grid
    }

    /// Light-field samples per band.
    pub fn n_samples(&self) -> usize {
        self.transports[0].n_samples()
    }

    /// Retinal pixels.
    pub fn n_pixels(&self) -> usize {
        self.transports[0].n_pixels()
    }

    /// OSA indices of the derivatives ∂T/∂W_j its operators carry.
    pub fn derivative_terms(&self) -> &[usize] {
        &self.transports[0].derivative_terms
    }

    /// True when each band has its own operator (wave optics).
    pub fn per_band(&self) -> bool {
        self.transports.len() > 1
    }

    /// S = Σ_n c_n ⊗ T_n L_n with coupling `c` (`c[n][a]`), or with ∂T_n/∂W_term for `Some(term)` (the k-th
    /// stored derivative): `l[p·N + n]` → `out[r·3 + a]`.
    pub fn forward_with(&self, term: Option<usize>, l: &[f32], c: &[[f32; 3]], out: &mut [f32]) {
        if let [t] = self.transports.as_slice() {
            match term {
                None => t.forward_lms(l, c, out),
                Some(k) => t.derivative_forward_lms(k, l, c, out),
            }
            return;
        }
        for (n, t) in self.transports.iter().enumerate() {
            t.forward_band_lms(term, l, c.len(), n, c[n], n > 0, out);
        }
    }

    /// The adjoint of [`Self::forward_with`]: `y[r·3 + a]` → `out[p·N + n]`.
    pub fn adjoint_with(&self, term: Option<usize>, y: &[f32], c: &[[f32; 3]], out: &mut [f32]) {
        if let [t] = self.transports.as_slice() {
            match term {
                None => t.adjoint_lms(y, c, out),
                Some(k) => t.derivative_adjoint_lms(k, y, c, out),
            }
            return;
        }
        for (n, t) in self.transports.iter().enumerate() {
            t.adjoint_band_lms(term, y, c.len(), n, c[n], out);
        }
    }

    /// The padding a [`GatheredField`] needs for every band's forward product, when each band has its own
    /// operator held as per-view kernels; `None` otherwise (then only the plain products serve).
    pub fn gather_pad(&self) -> Option<usize> {
        if !self.per_band() {
            return None;
        }
        self.transports
            .iter()
            .map(|t| t.stencil().map(|st| st.gather_pad()))
            .try_fold(0, |pad, p| p.map(|p| pad.max(p)))
    }

    /// Every band's operator as per-view kernels, when each band has its own (wave optics) and all are held
    /// so; `None` otherwise.
    pub fn band_stencils(&self) -> Option<Vec<&StencilOperator>> {
        if !self.per_band() {
            return None;
        }
        self.transports.iter().map(|t| t.stencil()).collect()
    }

    /// Which bands' products run by stencils (and read a [`GatheredField`]).
    pub fn stencil_bands(&self) -> Vec<bool> {
        self.transports
            .iter()
            .map(|t| t.product_method() == Some(crate::physics::transport::ProductMethod::Stencil))
            .collect()
    }

    /// Bands `bands` of `l` gathered once for the forward products of every observer on this display whose
    /// [`Self::gather_pad`] is at most `pad`.
    pub fn gather(&self, l: &[f32], bands: &[usize], pad: usize) -> GatheredField {
        let st = self.transports[0].stencil().expect("an operator held as stencils");
        st.gather(l, self.coupling.len(), bands, pad)
    }

    /// `out` = 2μ·x + Σ_k c·(observer k's [`Self::adjoint_planes`]), written into the light field once, the
    /// observers' planes added in the order given ([`StencilOperator::combine_planes`]; every observer on this
    /// display held as per-view kernels).
    ///
    /// [`StencilOperator::combine_planes`]: crate::physics::transport::StencilOperator::combine_planes
    pub fn combine_planes(&self, x: &[f32], mu: f32, c: f32, planes: &[&[f32]], out: &mut [f32]) {
        let st = self.transports[0].stencil().expect("an operator held as stencils");
        st.combine_planes(x, mu, c, planes, self.coupling.len(), out);
    }

    /// [`Self::forward_lms`] of `l` with `l` also gathered (`source`): the same image bit for bit
    /// ([`Self::gather_pad`] must be `Some`).
    pub fn forward_gathered(&self, source: &GatheredField, l: &[f32], out: &mut [f32]) {
        let n_bands = self.coupling.len();
        for (n, t) in self.transports.iter().enumerate() {
            let st = t.stencil().expect("an operator held as stencils");
            st.forward_from(None, Some(source), l, n_bands, n, self.coupling[n], n > 0, out);
        }
    }

    /// Floats of [`Self::adjoint_planes`]'s output: every band's planes, one band after another.
    pub fn planes_len(&self) -> usize {
        self.transports
            .iter()
            .map(|t| t.stencil().map_or(0, |st| st.plane_len()))
            .sum()
    }

    /// [`Self::adjoint_lms`] before it is written into the light field: band n's
    /// [`StencilOperator::adjoint_planes`] at `planes[n·plane_len..]` (overwritten; [`Self::gather_pad`] must
    /// be `Some`).
    ///
    /// [`StencilOperator::adjoint_planes`]: crate::physics::transport::StencilOperator::adjoint_planes
    pub fn adjoint_planes(&self, y: &[f32], planes: &mut [f32]) {
        assert_eq!(planes.len(), self.planes_len(), "planes length");
        let mut rest = planes;
        for (n, t) in self.transports.iter().enumerate() {
            let st = t.stencil().expect("an operator held as stencils");
            let (band, tail) = rest.split_at_mut(st.plane_len());
            st.adjoint_planes(None, y, self.coupling[n], band);
            rest = tail;
        }
    }

    /// S = (C ⊗ T)·L (Eq. 13) with this observer's coupling.
    pub fn forward_lms(&self, l: &[f32], out: &mut [f32]) {
        self.forward_with(None, l, &self.coupling, out);
    }

    /// The adjoint of [`Self::forward_lms`].
    pub fn adjoint_lms(&self, y: &[f32], out: &mut [f32]) {
        self.adjoint_with(None, y, &self.coupling, out);
    }

    /// The LMS retinal image `[r·3 + a]` of light field `l`.
    pub fn view(&self, l: &[f32]) -> Vec<f32> {
        let mut out = vec![0f32; self.n_pixels() * 3];
        self.forward_lms(l, &mut out);
        out
    }

    /// What this observer perceives of `view`, as an sRGB picture.
    pub fn picture(&self, view: &[f32]) -> RgbImage {
        let g = self.grid();
        imaging::lms_to_srgb_image(view, g.width, g.height, self.white)
    }

    /// The objective LMS image for this observer of an sRGB image (resized to the retinal grid).
    pub fn objective(&self, img: &RgbImage, level: f64) -> Vec<f32> {
        let g = self.grid();
        let resized = imaging::resize(img, g.width, g.height);
        imaging::objective_lms(&imaging::linear_rgb(&resized), self.white, level)
    }
}

/// The optics in front of an observer's sensor, at the viewing pupil.
#[derive(Clone, Copy, Debug)]
pub enum Lens<'a> {
    /// An eye: its wavefront measured at `reference_nm`; under wave optics each band adds the eye's chromatic
    /// defocus relative to it (Thibos et al. 1992).
    Eye {
        /// The wavefront at the viewing pupil.
        wavefront: &'a ZernikeCoefficients,
        /// The wavelength the coefficients were measured at, nm.
        reference_nm: f64,
    },
    /// An achromatic lens (a camera's): the same wavefront at every wavelength.
    Achromat(&'a ZernikeCoefficients),
}

impl Lens<'_> {
    fn wavefront(&self) -> &ZernikeCoefficients {
        match self {
            Lens::Eye { wavefront, .. } => wavefront,
            Lens::Achromat(w) => w,
        }
    }

    /// The wavefront at `wavelength_nm`.
    fn at(&self, wavelength_nm: f64) -> ZernikeCoefficients {
        match self {
            Lens::Eye {
                wavefront,
                reference_nm,
            } => crate::physics::chromatic::at_wavelength(wavefront, wavelength_nm, *reference_nm),
            Lens::Achromat(w) => (*w).clone(),
        }
    }
}

/// The transport operators of `lens` at `eye`: one (geometric optics) or one per band (wave optics: each band's
/// light as `options.wavelengths_per_band` wavelengths of equal power, each with its diffraction and the
/// lens's chromatic defocus, mixed: T_n = (1/q) Σ_q T(λ_q)).
pub fn transports(
    display: &DisplayGeometry,
    lens: Lens<'_>,
    eye: EyePosition,
    options: &TransportOptions,
    optics: Optics,
    cache: &TransportCache,
) -> Result<Vec<Arc<TransportMatrix>>, TransportError> {
    match optics {
        Optics::Geometric => {
            let opts = TransportOptions {
                wave: None,
                ..options.clone()
            };
            Ok(vec![cache.get_or_build(display, lens.wavefront(), eye, &opts)?])
        }
        Optics::Wave => {
            let pupil_mm = 2.0 * lens.wavefront().pupil_radius_mm();
            let q = options.wavelengths_per_band.max(1);
            display
                .projectors
                .iter()
                .map(|p| {
                    // The band as q wavelengths of equal power, the rays shared among them.
                    let lambdas = p.band_wavelengths_nm(q as usize);
                    let part_options = |lambda: f64| TransportOptions {
                        sub_rays: options.sub_rays.div_ceil(q),
                        wave: Some(WaveSampling {
                            wavelength_nm: lambda,
                            neighbour_blocks: neighbour_blocks(display, lambda, pupil_mm, eye),
                            kernel_rays: KERNEL_RAYS_PER_SUB_RAY * options.sub_rays / q,
                        }),
                        ..options.clone()
                    };
                    if q == 1 {
                        return cache.get_or_build(display, &lens.at(lambdas[0]), eye, &part_options(lambdas[0]));
                    }
                    let parts: Vec<(ZernikeCoefficients, TransportOptions)> =
                        lambdas.iter().map(|&l| (lens.at(l), part_options(l))).collect();
                    let key = serde_json::Value::Array(
                        parts
                            .iter()
                            .map(|(w, o)| TransportCache::key(display, w, eye, o))
                            .collect(),
                    )
                    .to_string();
                    cache.get_or_insert_with(key, || {
                        let built = parts
                            .iter()
                            .map(|(w, o)| TransportMatrix::build(display, w, eye, o))
                            .collect::<Result<Vec<_>, _>>()?;
                        let weighted: Vec<(f64, &TransportMatrix)> =
                            built.iter().map(|t| (1.0 / q as f64, t)).collect();
                        Ok(TransportMatrix::mix(&weighted))
                    })
                })
                .collect()
        }
    }
}

/// The light field of an ordinary 2D picture on the display: the document resampled to one value per hole,
/// turned into projector intensities for the standard observer, every view of a hole equal (paper Fig. 13).
pub fn plain_light_field_for_image(display: &DisplayGeometry, img: &RgbImage) -> Vec<f32> {
    let resized = imaging::resize(img, display.holes_x, display.holes_y);
    let c = coupling(&display.projectors, crate::physics::spectral::stockman_sharpe_2deg());
    let per_hole: Vec<f32> = imaging::plain_intensities(&imaging::linear_rgb(&resized), &c.c)
        .into_iter()
        .map(|v| v * display.l_max as f32)
        .collect();
    crate::physics::transport::plain_light_field(display, &per_hole)
}

/// Which forward model a simulation uses (docs/design.md §2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Optics {
    /// Straight rays, one transport for every band, each aperture's light normalised (the paper's idealisation).
    Geometric,
    /// Fraunhofer diffraction at the apertures, the eye's chromatic defocus per band, light through
    /// neighbouring blocks, physical brightness.
    #[default]
    Wave,
}

/// Sub-rays per view and neighbouring block of the shift-invariant kernels (docs/design.md §2.7), per sub-ray
/// a per-sample trace would spend on each light-field sample: at the default 16 that is 2048, whose relative
/// Monte-Carlo noise, about 1/√(rays entering the pupil), is under 3 % for a view that lies in it; every sample
/// shares it.
pub const KERNEL_RAYS_PER_SUB_RAY: u32 = 128;

/// Blocks on each side of the block an eye looks at through an aperture whose light can still reach a pupil
/// of `pupil_mm`: light from m blocks over arrives m·p_h(1 + g/d)·d/g off the view's aim, spread by the block's
/// fan (its views, and the aperture's own width projected to the pupil) and by diffraction out to the radius
/// holding 90 % of the light (2.23·λ/a for a hole's Airy pattern, λ/A per axis for a lenslet's sinc²).
///
/// The window is centred on the block nearest the eye's line of sight through each aperture, so an eye off that
/// line by up to half a block adds its distance from it.
pub fn neighbour_blocks(display: &DisplayGeometry, wavelength_nm: f64, pupil_mm: f64, eye: EyePosition) -> u32 {
    let d = display.viewing_distance_mm;
    let a = display.hole_diameter_mm;
    let lambda_mm = wavelength_nm * 1e-6;
    let (spread, aperture_half) = match display.aperture {
        crate::physics::display::Aperture::Pinhole => (2.23 * lambda_mm * d / a, 0.5 * a * (1.0 + d / display.gap_mm)),
        crate::physics::display::Aperture::Lenslet => (lambda_mm * d / a, 0.5 * a),
    };
    let views = display.views_u.max(display.views_v) as f64;
    let fan_half = 0.5 * views * display.view_spacing_at_pupil_mm() + aperture_half;
    let per_block = display.block_shift_at_pupil_mm(d + eye.dz_mm);
    let residual = |e: f64| (e - (e / per_block).round() * per_block).abs();
    // At the design distance every aperture shows the eye the same block (`transport::block_seen`); nearer or
    // farther the block differs across the display, and an aperture's line of sight can be off its block's
    // aim by up to half a block either way.
    let off_line = if eye.dz_mm == 0.0 {
        residual(eye.x_mm).hypot(residual(eye.y_mm))
    } else {
        0.5 * per_block * std::f64::consts::SQRT_2
    };
    (((pupil_mm / 2.0 + fan_half + spread + off_line) / per_block).floor() as u32).min(16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_per_band_products_are_adjoint_and_add_up_the_bands() {
        // ⟨A L, y⟩ = ⟨L, Aᵀ y⟩ for the per-band operator S = Σ_n c_n ⊗ T_n L_n (relative 1e-5, f32), and A L
        // equals the sum of the bands seen one at a time.
        let d = DisplayGeometry {
            holes_x: 10,
            holes_y: 8,
            ..DisplayGeometry::paper()
        };
        let mut p = VisionProfile::perfect();
        p.zernike_um[4] = 0.3;
        let opts = TransportOptions {
            sub_rays: 4,
            derivative_terms: vec![4],
            ..Default::default()
        };
        let o = Observer::new(
            &d,
            &p,
            EyePosition::default(),
            &opts,
            Optics::Wave,
            &TransportCache::disabled(),
        )
        .unwrap();
        assert!(o.per_band());
        let l: Vec<f32> = (0..o.n_samples() * d.n_bands())
            .map(|i| ((i * 37 % 101) as f32) / 101.0)
            .collect();
        let y: Vec<f32> = (0..o.n_pixels() * 3).map(|i| ((i * 53 % 97) as f32) / 97.0).collect();
        for term in [None, Some(0)] {
            let mut al = vec![0f32; y.len()];
            let mut aty = vec![0f32; l.len()];
            o.forward_with(term, &l, &o.coupling, &mut al);
            o.adjoint_with(term, &y, &o.coupling, &mut aty);
            let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum::<f64>();
            let (lhs, rhs) = (dot(&al, &y), dot(&l, &aty));
            assert!((lhs - rhs).abs() <= 1e-5 * lhs.abs(), "{term:?}: {lhs} vs {rhs}");
        }
        let whole = o.view(&l);
        let mut sum = vec![0f32; whole.len()];
        for n in 0..d.n_bands() {
            let one: Vec<[f32; 3]> = (0..d.n_bands())
                .map(|m| if m == n { o.coupling[m] } else { [0.0; 3] })
                .collect();
            let mut part = vec![0f32; whole.len()];
            o.forward_with(None, &l, &one, &mut part);
            sum.iter_mut().zip(&part).for_each(|(s, v)| *s += v);
        }
        for (a, b) in whole.iter().zip(&sum) {
            assert!((a - b).abs() <= 1e-5 * a.abs().max(1e-3), "{a} vs {b}");
        }
    }

    #[test]
    fn at_the_design_distance_a_wide_spread_is_held_as_stencils_and_a_traced_one_too_large_is_refused() {
        // The `dense` preset's 33 µm holes spread every pixel's light through 7×7 apertures at 450 nm. At the
        // design distance one band's operator is 81 view kernels: a few MiB in all, where the expanded sparse
        // form took 2.7 GiB.
        let cache = TransportCache::disabled();
        let p = VisionProfile::perfect();
        let opts = TransportOptions {
            sub_rays: 1,
            ..Default::default()
        };
        let ok = Observer::new(
            &DisplayGeometry::dense(),
            &p,
            EyePosition::default(),
            &opts,
            Optics::Wave,
            &cache,
        )
        .expect("the dense preset builds under wave optics");
        assert!(ok.transports.iter().all(|t| t.is_stencil()));
        let bytes: usize = ok.transports.iter().map(|t| t.memory_bytes()).sum();
        assert!(bytes < 8 << 20, "{bytes}");
        // Kernels this wide are applied by FFT (its work does not grow with the taps), from the second product
        // on: the first, by stencils, and the second agree to f32 rounding, and the spectra stay within bounds.
        assert!(ok
            .transports
            .iter()
            .all(|t| t.product_method() == Some(crate::physics::transport::ProductMethod::Fft)));
        let t = &ok.transports[0];
        let l: Vec<f32> = (0..t.n_samples()).map(|i| ((i * 7919) % 101) as f32 / 101.0).collect();
        let mut first = vec![0f32; t.n_pixels() * 3];
        let mut second = first.clone();
        t.forward_band_lms(None, &l, 1, 0, [1.0, 0.5, 0.25], false, &mut first);
        t.forward_band_lms(None, &l, 1, 0, [1.0, 0.5, 0.25], false, &mut second);
        let peak = first.iter().fold(0f32, |m, v| m.max(v.abs()));
        let worst = first.iter().zip(&second).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(peak > 0.0 && worst < 1e-4 * peak, "{worst} of {peak}");
        let with_spectra: usize = ok.transports.iter().map(|t| t.memory_bytes()).sum();
        assert!(with_spectra > bytes && with_spectra < 12 << 20, "{with_spectra}");
        // An eye 100 mm farther is traced sample by sample; on the lenslet preset that operator takes about
        // 15 MiB per band. Under a 4 MiB bound it is refused, with the reason, before T is assembled.
        let far = EyePosition {
            dz_mm: 100.0,
            ..Default::default()
        };
        let opts = TransportOptions {
            sub_rays: 16,
            max_traced_wave_bytes: 4 << 20,
            ..Default::default()
        };
        let err = match Observer::new(&DisplayGeometry::lenslet(), &p, far, &opts, Optics::Wave, &cache) {
            Ok(o) => panic!("built {} MiB", o.transports[0].memory_bytes() >> 20),
            Err(e) => e,
        };
        let text = err.to_string();
        assert!(
            matches!(err, ObserverError::Transport(TransportError::OverBudget { .. })),
            "{text}"
        );
        assert!(text.contains("geometric") && text.contains("MiB"), "{text}");
    }
}
