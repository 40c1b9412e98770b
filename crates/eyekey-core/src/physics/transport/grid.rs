//! Where a viewer is and how a transport build samples: the retinal grid, the eye position, the build options.

use crate::physics::display::DisplayGeometry;

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
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct EyePosition {
    /// Lateral offset, mm.
    pub x_mm: f64,
    /// Vertical offset, mm.
    pub y_mm: f64,
    /// Change of viewing distance from the display's design distance, mm (positive = farther).
    pub dz_mm: f64,
}

/// Wavelengths per band by default: across a 20 nm band the eye's chromatic defocus changes by up to 0.23 D
/// (450 nm), up to 0.7 mm of blur at the display for a 6 mm pupil (docs/design.md §2.7).
pub const DEFAULT_WAVELENGTHS_PER_BAND: u32 = 3;

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
    /// Wave-optics sampling for one wavelength; `None` is the geometric model (docs/design.md §2).
    pub wave: Option<WaveSampling>,
    /// The most memory a wave-optics operator traced sample by sample (an eye off the design distance) may
    /// take, bytes; a build that would exceed it stops with [`super::TransportError::OverBudget`].
    pub max_traced_wave_bytes: usize,
    /// Wavelengths that stand for each band under wave optics (equal-power bins of its spectrum, each with its
    /// own diffraction and chromatic defocus; the rays are shared among them); 1 is the centroid alone.
    pub wavelengths_per_band: u32,
    /// How the shift-invariant kernels' sub-rays are drawn (docs/design.md §2.7).
    pub sequence: SubRaySequence,
    /// The frames are re-indexed for this eye ([`crate::physics::tracking::retarget`]): the operator is T·R, what
    /// the eye sees of frames encoded for the design position and shown re-indexed for it, so that the encoder
    /// can ask a tracked eye for the document. Wave-optics builds at the design distance only (per-view kernels).
    pub tracked: bool,
}

/// How the shift-invariant kernels are made: by quadrature where the display allows (lenslets: no sub-ray, no
/// sampling noise), else from sub-rays, each drawing six uniforms (its point in the aperture, in the screen pixel,
/// and its diffraction angle). Both sequences give every kernel as an unbiased estimate; the low-discrepancy one
/// spreads one block's sub-rays evenly over the six dimensions, so the kernels' noise is lower for the same number
/// of sub-rays (docs/design.md §2.7, BENCHMARKS.md "Kernel sampling").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SubRaySequence {
    /// Lenslet displays: no sub-rays, a deterministic quadrature over the pupil (docs/design.md §2.7); pinhole
    /// displays: as [`Self::Kronecker`].
    #[default]
    Quadrature,
    /// The R₆ Kronecker sequence, shifted at random per view and block (randomised quasi-Monte Carlo).
    Kronecker,
    /// Independent uniform draws (plain Monte Carlo), for comparison.
    Independent,
}

/// How a wave-optics build samples one band (docs/design.md §2, "Wave optics").
///
/// Each sub-ray gets a Fraunhofer diffraction angle drawn from its aperture's pattern at `wavelength_nm`
/// (Airy for a pinhole, sinc² per axis for a lenslet), and every aperture passes light from the screen pixels
/// of its own block and of `neighbour_blocks` blocks around it, so light leaking through a neighbouring hole
/// reaches the eye too. Brightness is physical: one constant per build (the eye's adaptation) makes the
/// centre aperture of a plain image as bright as the image; every other aperture is as bright as the light
/// that actually enters the pupil through it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WaveSampling {
    /// Wavelength of the band, nm.
    pub wavelength_nm: f64,
    /// Blocks of screen pixels on each side of an aperture's own block whose light it passes.
    pub neighbour_blocks: u32,
    /// Sub-rays per view and neighbouring block of the shift-invariant kernels that build T at the design
    /// distance (docs/design.md §2.7); 0, or an eye nearer or farther, traces every light-field sample with
    /// `sub_rays` instead.
    pub kernel_rays: u32,
}

impl Default for TransportOptions {
    fn default() -> Self {
        Self {
            sub_rays: 16,
            seed: 7,
            retina_oversample: 1,
            derivative_terms: Vec::new(),
            wave: None,
            max_traced_wave_bytes: super::MAX_WAVE_OPERATOR_BYTES,
            wavelengths_per_band: DEFAULT_WAVELENGTHS_PER_BAND,
            sequence: SubRaySequence::default(),
            tracked: false,
        }
    }
}
