//! An observer of the display: one person (or camera) at one eye position, with their transport operator and
//! their spectral coupling (Eq. 13: S_a = Σ_n c_na T L_n).

use std::sync::Arc;

use image::RgbImage;

use crate::imaging;
use crate::physics::display::DisplayGeometry;
use crate::physics::profile::{ProfileError, VisionProfile};
use crate::physics::spectral::{coupling, ConeFundamentals};
use crate::physics::transport::{
    EyePosition, TransportCache, TransportError, TransportMatrix, TransportOptions, WaveSampling,
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

/// One observer: transport operator plus spectral coupling.
#[derive(Clone, Debug)]
pub struct Observer {
    /// Transport from the light field to this observer's retinal grid.
    pub transport: Arc<TransportMatrix>,
    /// c_na per band n, as f32 for the kernels.
    pub coupling: Vec<[f32; 3]>,
    /// c_na per band n.
    pub coupling_f64: Vec<[f64; 3]>,
    /// The LMS of the display's white (every projector at L_max) for this observer.
    pub white: [f64; 3],
}

impl Observer {
    /// Builds the observer for `profile` at `eye`, taking its transport operator from `cache` (built and
    /// stored there if absent).
    pub fn new(
        display: &DisplayGeometry,
        profile: &VisionProfile,
        eye: EyePosition,
        options: &TransportOptions,
        cache: &TransportCache,
    ) -> Result<Self, ObserverError> {
        profile.validate()?;
        let wavefront = profile.effective_wavefront()?;
        Self::from_parts(display, &wavefront, &profile.cone_fundamentals(), eye, options, cache)
    }

    /// Builds an observer from a wavefront at the viewing pupil and cone fundamentals.
    pub fn from_parts(
        display: &DisplayGeometry,
        wavefront: &ZernikeCoefficients,
        cones: &ConeFundamentals,
        eye: EyePosition,
        options: &TransportOptions,
        cache: &TransportCache,
    ) -> Result<Self, ObserverError> {
        let transport = cache.get_or_build(display, wavefront, eye, options)?;
        let c = coupling(&display.projectors, cones);
        Ok(Self::with_coupling(transport, c.c, display.l_max))
    }

    /// An observer from a transport operator and a coupling matrix.
    pub fn with_coupling(transport: Arc<TransportMatrix>, coupling_f64: Vec<[f64; 3]>, l_max: f64) -> Self {
        let white = std::array::from_fn(|a| coupling_f64.iter().map(|c| c[a]).sum::<f64>() * l_max);
        let coupling = coupling_f64
            .iter()
            .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
            .collect();
        Self {
            transport,
            coupling,
            coupling_f64,
            white,
        }
    }

    /// The LMS retinal image `[r·3 + a]` of light field `l`.
    pub fn view(&self, l: &[f32]) -> Vec<f32> {
        let mut out = vec![0f32; self.transport.n_pixels() * 3];
        self.transport.forward_lms(l, &self.coupling, &mut out);
        out
    }

    /// What this observer perceives of `view`, as an sRGB picture.
    pub fn picture(&self, view: &[f32]) -> RgbImage {
        let g = self.transport.grid;
        imaging::lms_to_srgb_image(view, g.width, g.height, self.white)
    }

    /// The objective LMS image for this observer of an sRGB image (resized to the retinal grid).
    pub fn objective(&self, img: &RgbImage, level: f64) -> Vec<f32> {
        let g = self.transport.grid;
        let resized = imaging::resize(img, g.width, g.height);
        imaging::objective_lms(&imaging::linear_rgb(&resized), self.white, level)
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
#[serde(rename_all = "snake_case")]
pub enum Optics {
    /// Straight rays, one transport for every band, each aperture's light normalised (the paper's idealisation).
    #[default]
    Geometric,
    /// Fraunhofer diffraction at the apertures, the eye's chromatic defocus per band, light through
    /// neighbouring blocks, physical brightness.
    Wave,
}

/// An observer under wave optics: one transport per band, each at the band's centroid wavelength with the eye's
/// chromatic defocus (Thibos et al. 1992) and the aperture's diffraction; the view is S_a = Σ_n c_na T_n L_n
/// (paper Eq. 13 with a band-dependent T).
#[derive(Clone, Debug)]
pub struct WaveObserver {
    /// One observer per band n, its coupling zero outside band n.
    pub bands: Vec<Observer>,
    /// The LMS of the display's white for this observer.
    pub white: [f64; 3],
}

impl WaveObserver {
    /// Builds the per-band transports for `profile` at `eye`.
    pub fn new(
        display: &DisplayGeometry,
        profile: &VisionProfile,
        eye: EyePosition,
        options: &TransportOptions,
        cache: &TransportCache,
    ) -> Result<Self, ObserverError> {
        profile.validate()?;
        let c = coupling(&display.projectors, &profile.cone_fundamentals()).c;
        let white = std::array::from_fn(|a| c.iter().map(|row| row[a]).sum::<f64>() * display.l_max);
        let mut bands = Vec::with_capacity(display.n_bands());
        for (n, p) in display.projectors.iter().enumerate() {
            let lambda = p.centroid_nm();
            let wave = WaveSampling {
                wavelength_nm: lambda,
                neighbour_blocks: neighbour_blocks(display, lambda, profile.pupil_diameter_mm),
            };
            let opts = TransportOptions {
                wave: Some(wave),
                ..options.clone()
            };
            let transport = cache.get_or_build(display, &profile.wavefront_at(lambda)?, eye, &opts)?;
            let masked = (0..c.len()).map(|m| if m == n { c[m] } else { [0.0; 3] }).collect();
            bands.push(Observer::with_coupling(transport, masked, display.l_max));
        }
        Ok(Self { bands, white })
    }

    /// The LMS retinal image `[r·3 + a]` of light field `l`.
    pub fn view(&self, l: &[f32]) -> Vec<f32> {
        let mut out = self.bands[0].view(l);
        for b in &self.bands[1..] {
            for (o, v) in out.iter_mut().zip(b.view(l)) {
                *o += v;
            }
        }
        out
    }

    /// What this observer perceives of `view`, as an sRGB picture.
    pub fn picture(&self, view: &[f32]) -> RgbImage {
        let g = self.bands[0].transport.grid;
        imaging::lms_to_srgb_image(view, g.width, g.height, self.white)
    }
}

/// Blocks on each side of the block an eye looks at through an aperture whose light can still reach a pupil
/// of `pupil_mm`: light from k blocks over arrives k·p_h(1 + g/d)·d/g off the view's aim, so k covers the
/// diffraction spread 1.22λd/A plus the pupil's radius, with one block to spare.
pub fn neighbour_blocks(display: &DisplayGeometry, wavelength_nm: f64, pupil_mm: f64) -> u32 {
    let d = display.viewing_distance_mm;
    let spread = 1.22 * wavelength_nm * 1e-6 * d / display.hole_diameter_mm;
    let per_block = display.block_shift_at_pupil_mm(d);
    (((spread + pupil_mm / 2.0) / per_block).ceil() as u32 + 1).min(16)
}
