//! The 5D light-field display (paper §5): a barrier of holes in front of a rear-projected multiband screen.
//!
//! Conventions (docs/design.md §2): X×Y holes at pitch `hole_pitch_mm` in the barrier plane (z = 0), the screen at
//! distance `gap_mm` behind it. Behind each hole lie U×V screen pixels at pitch `screen_pixel_pitch_mm`; the
//! pixel at offset (i, j) sends its light through the hole with slope −offset/g (Eq. 13's light field
//! L(x, y, u, v, n) is the set of N projector frames). The blocks behind the holes are aimed at the design eye
//! position, so the block pitch is p_h·(1 + g/d) rather than p_h.

use serde::{Deserialize, Serialize};

use crate::physics::spectral::ProjectorSpectrum;

/// Errors in a display description. Every message names the field.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum DisplayError {
    /// A numeric field is outside its physical range.
    #[error("{field} must be within {min}..={max} {unit}, got {value}")]
    OutOfRange {
        /// The field's name.
        field: &'static str,
        /// The offending value.
        value: f64,
        /// Lower bound.
        min: f64,
        /// Upper bound.
        max: f64,
        /// Unit of the bounds.
        unit: &'static str,
    },
    /// A combination of fields is inconsistent.
    #[error("{field}: {reason}")]
    Inconsistent {
        /// The field's name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A projector spectrum is invalid.
    #[error("projectors[{index}]: {reason}")]
    Projector {
        /// Index of the projector.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// An unknown preset name.
    #[error("unknown display preset {0:?} (known: paper, secure, small, lenslet, pinhole, dense)")]
    UnknownPreset(String),
}

/// What sits in front of the screen: a barrier of circular holes, or an array of square lenslets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Aperture {
    /// Circular holes of `hole_diameter_mm` in an opaque barrier `gap_mm` in front of the screen.
    #[default]
    Pinhole,
    /// Square lenslets of side `hole_diameter_mm` (normally the pitch) and focal length `gap_mm`, the screen at
    /// their focal plane: each pixel point leaves as a collimated beam of slope (h − q)/f.
    Lenslet,
}

impl Aperture {
    /// The name used in JSON: `pinhole` or `lenslet`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Pinhole => "pinhole",
            Self::Lenslet => "lenslet",
        }
    }
}

/// Geometry and spectra of a 5D light-field display, plus the viewing distance it is designed for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct DisplayGeometry {
    /// Pinhole barrier or lenslet array (default: pinhole).
    #[serde(default)]
    pub aperture: Aperture,
    /// Holes across (X), 1–1024.
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 1024))]
    pub holes_x: u32,
    /// Holes down (Y), 1–1024.
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 1024))]
    pub holes_y: u32,
    /// Centre-to-centre distance of the holes, mm (0.01–10).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.01, maximum = 10.0))]
    pub hole_pitch_mm: f64,
    /// Diameter of each (circular) hole, mm (0.001–10, at most the pitch).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.001, maximum = 10.0))]
    pub hole_diameter_mm: f64,
    /// Screen pixels behind each hole, horizontally (U), 1–32.
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 32))]
    pub views_u: u32,
    /// Screen pixels behind each hole, vertically (V), 1–32.
    #[cfg_attr(feature = "openapi", schema(minimum = 1, maximum = 32))]
    pub views_v: u32,
    /// Screen pixel pitch, mm (0.001–10, with U·p_s ≤ p_h).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.001, maximum = 10.0))]
    pub screen_pixel_pitch_mm: f64,
    /// Distance from the screen to the barrier, mm (0.1–1000).
    #[cfg_attr(feature = "openapi", schema(minimum = 0.1, maximum = 1000.0))]
    pub gap_mm: f64,
    /// Design viewing distance from the barrier to the pupil, mm (50–10000).
    #[cfg_attr(feature = "openapi", schema(minimum = 50.0, maximum = 10000.0))]
    pub viewing_distance_mm: f64,
    /// One spectral power distribution per projector (band).
    #[cfg_attr(feature = "openapi", schema(min_items = 1))]
    pub projectors: Vec<ProjectorSpectrum>,
    /// Largest light-field value a projector pixel can emit (Eq. 15), 10⁻⁶–10⁶; frames store L / L_max.
    #[cfg_attr(feature = "openapi", schema(minimum = 0.000001, maximum = 1000000.0))]
    pub l_max: f64,
}

/// Names of the built-in presets.
pub const PRESETS: &[&str] = &["paper", "secure", "small", "lenslet", "pinhole", "dense"];

impl DisplayGeometry {
    /// The paper's synthesized setup (§7.3): 100×100 holes, 5×5 views, 4 narrow-band projectors.
    ///
    /// Numbers: hole pitch 0.4 mm (a 40 mm square barrier), U = V = 5 screen pixels of 0.08 mm behind each
    /// hole (filling the pitch), gap 33.3 mm, viewing distance 500 mm. Adjacent views are then
    /// p_s·d/g = 1.2 mm apart at the pupil, so the 5 views of a hole span 6 mm: about 3×3 to 5×5 of them
    /// cross a 6 mm pupil, which is what lets the light field act on the eye's aberrations. A hole of
    /// 0.08 mm (one screen pixel) keeps each view's footprint at the pupil to (p_s + hole)·d/g = 2.4 mm.
    pub fn paper() -> Self {
        Self {
            aperture: Default::default(),
            holes_x: 100,
            holes_y: 100,
            hole_pitch_mm: 0.4,
            hole_diameter_mm: 0.08,
            views_u: 5,
            views_v: 5,
            screen_pixel_pitch_mm: 0.08,
            gap_mm: 0.08 * 500.0 / 1.2,
            viewing_distance_mm: 500.0,
            projectors: crate::physics::spectral::paper_projectors(),
            l_max: 1.0,
        }
    }

    /// The display eyekey's secrecy is measured on (docs/experiments.md §2b–§2d): 32×32 square lenslets of
    /// 1 mm (a 32 mm square, room for a PIN slip), 9×9 views, the screen at their focal plane 92.6 mm behind.
    ///
    /// Optically it is the `lenslet` preset on a smaller array: views p_s·d/f = (1/9 mm)·500/92.6 = 0.6 mm apart
    /// at the pupil, resolvability 1.9–2.7 per band, and every lenslet's block of views repeats at the pupil
    /// every p_h(1 + f/d)·d/f = 6.4 mm. Fewer lenslets keep the encode within seconds; the default encode
    /// options were chosen on it (docs/experiments.md §2d).
    pub fn secure() -> Self {
        Self {
            holes_x: 32,
            holes_y: 32,
            ..Self::lenslet()
        }
    }

    /// A pinhole barrier dense in angle: 48×48 holes of 33 µm at 0.3 mm, 9×9 views 0.75 mm apart at the pupil.
    /// Its angular freedom exists under geometric optics only: diffraction at 33 µm holes spreads every view
    /// over about 10 mm at the pupil (resolvability 0.08–0.11), so it stands for displays that do not resolve
    /// their views, and for the wide kernels eyekey applies by FFT.
    pub fn dense() -> Self {
        let p_s = 0.3 / 9.0;
        Self {
            aperture: Default::default(),
            holes_x: 48,
            holes_y: 48,
            hole_pitch_mm: 0.3,
            hole_diameter_mm: p_s,
            views_u: 9,
            views_v: 9,
            screen_pixel_pitch_mm: p_s,
            gap_mm: p_s * 500.0 / 0.75,
            viewing_distance_mm: 500.0,
            projectors: crate::physics::spectral::paper_projectors(),
            l_max: 1.0,
        }
    }

    /// A lenslet display that resolves its views under diffraction (docs/design.md §2.7): 48×48 square
    /// lenslets of 1 mm (a 48 mm square), 9×9 views, the screen at their focal plane 92.6 mm behind them.
    ///
    /// Views are p_s·d/f = (1/9 mm)·500/92.6 = 0.6 mm apart at the pupil, and a lenslet's diffraction spreads a
    /// view by λd/A = 0.28 mm at 555 nm, so the resolvability A·s/(λd) is 2.2 (1.9 in the red band, 2.6 in the
    /// blue): about 10 views across a 6 mm pupil and 6 across a 4 mm one are distinct. The price is spatial:
    /// 1 mm pixels, because M ≤ A·s/(λd) ties the pixel size A to how finely the pupil can be sampled.
    pub fn lenslet() -> Self {
        let p_s = 1.0 / 9.0;
        Self {
            aperture: Aperture::Lenslet,
            holes_x: 48,
            holes_y: 48,
            hole_pitch_mm: 1.0,
            hole_diameter_mm: 1.0,
            views_u: 9,
            views_v: 9,
            screen_pixel_pitch_mm: p_s,
            gap_mm: p_s * 500.0 / 0.6,
            viewing_distance_mm: 500.0,
            projectors: crate::physics::spectral::paper_projectors(),
            l_max: 1.0,
        }
    }

    /// A pinhole barrier that resolves its views under diffraction: 48×48 holes of 0.15 mm at 0.75 mm pitch,
    /// 5×5 views, gap 30 mm.
    ///
    /// Views are 0.15·500/30 = 2.5 mm apart at the pupil and a hole's Airy core spreads a view by
    /// 1.22·λd/a = 2.3 mm at 555 nm, so A·s/(λd) = 1.35 (1.2 red, 1.7 blue). A barrier cannot do much better:
    /// a hole resolves views only if a > λd/s while it must stay below a screen pixel, a < p_s = s·g/d, so
    /// s² > λd²/g; finer view spacing needs an impractically deep gap (0.6 mm would need g ≈ 380 mm). Only
    /// about 2 views cross a 6 mm pupil, so this display directs views to eye positions (a bystander's seat
    /// sees other views) more than it acts on one eye's aberrations.
    pub fn pinhole() -> Self {
        Self {
            aperture: Aperture::Pinhole,
            holes_x: 48,
            holes_y: 48,
            hole_pitch_mm: 0.75,
            hole_diameter_mm: 0.15,
            views_u: 5,
            views_v: 5,
            screen_pixel_pitch_mm: 0.15,
            gap_mm: 30.0,
            viewing_distance_mm: 500.0,
            projectors: crate::physics::spectral::paper_projectors(),
            l_max: 1.0,
        }
    }

    /// A small display for tests and quick demos: 24×24 holes, 5×5 views, the `paper` optics.
    pub fn small() -> Self {
        Self {
            aperture: Default::default(),
            holes_x: 24,
            holes_y: 24,
            ..Self::paper()
        }
    }

    /// A preset by name (`paper`, `secure`, `small`, `lenslet`, `pinhole`, `dense`).
    pub fn preset(name: &str) -> Result<Self, DisplayError> {
        match name {
            "paper" => Ok(Self::paper()),
            "secure" => Ok(Self::secure()),
            "small" => Ok(Self::small()),
            "lenslet" => Ok(Self::lenslet()),
            "pinhole" => Ok(Self::pinhole()),
            "dense" => Ok(Self::dense()),
            other => Err(DisplayError::UnknownPreset(other.to_string())),
        }
    }

    /// Checks every field against its physical range and the fields against each other.
    pub fn validate(&self) -> Result<(), DisplayError> {
        fn range(field: &'static str, v: f64, min: f64, max: f64, unit: &'static str) -> Result<(), DisplayError> {
            if v.is_finite() && v >= min && v <= max {
                Ok(())
            } else {
                Err(DisplayError::OutOfRange {
                    field,
                    value: v,
                    min,
                    max,
                    unit,
                })
            }
        }
        range("holes_x", self.holes_x as f64, 1.0, 1024.0, "holes")?;
        range("holes_y", self.holes_y as f64, 1.0, 1024.0, "holes")?;
        range("views_u", self.views_u as f64, 1.0, 32.0, "views")?;
        range("views_v", self.views_v as f64, 1.0, 32.0, "views")?;
        range("hole_pitch_mm", self.hole_pitch_mm, 0.01, 10.0, "mm")?;
        range("hole_diameter_mm", self.hole_diameter_mm, 0.001, 10.0, "mm")?;
        range("screen_pixel_pitch_mm", self.screen_pixel_pitch_mm, 0.001, 10.0, "mm")?;
        range("gap_mm", self.gap_mm, 0.1, 1000.0, "mm")?;
        range("viewing_distance_mm", self.viewing_distance_mm, 50.0, 10000.0, "mm")?;
        range("l_max", self.l_max, 1e-6, 1e6, "")?;
        if self.hole_diameter_mm > self.hole_pitch_mm * (1.0 + 1e-9) {
            let what = match self.aperture {
                Aperture::Pinhole => "a hole",
                Aperture::Lenslet => "a lenslet",
            };
            return Err(DisplayError::Inconsistent {
                field: "hole_diameter_mm",
                reason: format!(
                    "{what} of {} mm does not fit the pitch of {} mm",
                    self.hole_diameter_mm, self.hole_pitch_mm
                ),
            });
        }
        let views_width = self.views_u.max(self.views_v) as f64 * self.screen_pixel_pitch_mm;
        if self.aperture == Aperture::Lenslet && views_width > self.hole_diameter_mm * (1.0 + 1e-9) {
            return Err(DisplayError::Inconsistent {
                field: "views_u",
                reason: format!(
                    "{} views of {} mm ({} mm) do not fit behind a lenslet of {} mm",
                    self.views_u.max(self.views_v),
                    self.screen_pixel_pitch_mm,
                    views_width,
                    self.hole_diameter_mm
                ),
            });
        }
        let block = self.views_u.max(self.views_v) as f64 * self.screen_pixel_pitch_mm;
        if block > self.hole_pitch_mm * (1.0 + 1e-9) {
            return Err(DisplayError::Inconsistent {
                field: "screen_pixel_pitch_mm",
                reason: format!(
                    "{} views of {} mm ({} mm) exceed the hole pitch of {} mm (U·p_s ≤ p_h)",
                    self.views_u.max(self.views_v),
                    self.screen_pixel_pitch_mm,
                    block,
                    self.hole_pitch_mm
                ),
            });
        }
        if self.projectors.is_empty() || self.projectors.len() > 16 {
            return Err(DisplayError::Inconsistent {
                field: "projectors",
                reason: format!("between 1 and 16 projectors are needed, got {}", self.projectors.len()),
            });
        }
        for (index, p) in self.projectors.iter().enumerate() {
            p.validate().map_err(|e| DisplayError::Projector {
                index,
                reason: e.to_string(),
            })?;
        }
        let samples = self.n_samples_per_band() as u64 * self.projectors.len() as u64;
        if samples > 64_000_000 {
            return Err(DisplayError::Inconsistent {
                field: "holes_x",
                reason: format!("the light field has {samples} unknowns; at most 64000000 are supported"),
            });
        }
        Ok(())
    }

    /// Number of projector bands N.
    pub fn n_bands(&self) -> usize {
        self.projectors.len()
    }

    /// Light-field samples per band: X·Y·U·V.
    pub fn n_samples_per_band(&self) -> usize {
        (self.holes_x * self.holes_y * self.views_u * self.views_v) as usize
    }

    /// Width and height of one projector frame in pixels: (X·U, Y·V).
    pub fn frame_size(&self) -> (u32, u32) {
        (self.holes_x * self.views_u, self.holes_y * self.views_v)
    }

    /// Centre of hole (x, y) in the barrier plane, mm, origin at the barrier's centre.
    pub fn hole_centre_mm(&self, x: u32, y: u32) -> [f64; 2] {
        [
            (x as f64 - (self.holes_x as f64 - 1.0) / 2.0) * self.hole_pitch_mm,
            (y as f64 - (self.holes_y as f64 - 1.0) / 2.0) * self.hole_pitch_mm,
        ]
    }

    /// Centre of screen pixel (i, j) behind hole (x, y), in screen-plane coordinates (mm, same axes).
    ///
    /// The block behind each hole is centred on the line from the design eye position (on axis) through
    /// the hole: block centre = h·(1 + g/d) (docs/design.md §2).
    pub fn screen_pixel_centre_mm(&self, x: u32, y: u32, i: u32, j: u32) -> [f64; 2] {
        let h = self.hole_centre_mm(x, y);
        let aim = 1.0 + self.gap_mm / self.viewing_distance_mm;
        [
            h[0] * aim + (i as f64 - (self.views_u as f64 - 1.0) / 2.0) * self.screen_pixel_pitch_mm,
            h[1] * aim + (j as f64 - (self.views_v as f64 - 1.0) / 2.0) * self.screen_pixel_pitch_mm,
        ]
    }

    /// How far apart, at a pupil `distance_mm` from the barrier, land the light of one aperture's own block
    /// and of the next block passing through the same aperture, mm: the block pitch p_h·(1 + g/d) times
    /// distance/g.
    pub fn block_shift_at_pupil_mm(&self, distance_mm: f64) -> f64 {
        self.hole_pitch_mm * (1.0 + self.gap_mm / self.viewing_distance_mm) * distance_mm / self.gap_mm
    }

    /// Distance between adjacent views where they cross the pupil plane, mm: p_s·d/g.
    pub fn view_spacing_at_pupil_mm(&self) -> f64 {
        self.screen_pixel_pitch_mm * self.viewing_distance_mm / self.gap_mm
    }

    /// Barrier width and height, mm.
    pub fn extent_mm(&self) -> [f64; 2] {
        [
            self.holes_x as f64 * self.hole_pitch_mm,
            self.holes_y as f64 * self.hole_pitch_mm,
        ]
    }

    /// Index of light-field sample (x, y, i, j) within one band, in frame (row-major) order:
    /// pixel (x·U + i, y·V + j) of an (X·U)×(Y·V) frame.
    pub fn sample_index(&self, x: u32, y: u32, i: u32, j: u32) -> usize {
        let width = (self.holes_x * self.views_u) as usize;
        (y * self.views_v + j) as usize * width + (x * self.views_u + i) as usize
    }

    /// Inverse of [`Self::sample_index`]: (x, y, i, j).
    pub fn sample_coords(&self, index: usize) -> (u32, u32, u32, u32) {
        let width = (self.holes_x * self.views_u) as usize;
        let (row, col) = ((index / width) as u32, (index % width) as u32);
        (
            col / self.views_u,
            row / self.views_v,
            col % self.views_u,
            row % self.views_v,
        )
    }

    /// The barrier mask as a binary image at `pixels_per_hole` pixels per hole pitch (1 = open).
    pub fn barrier_mask(&self, pixels_per_hole: u32) -> (u32, u32, Vec<u8>) {
        let k = pixels_per_hole.max(1);
        let (w, h) = (self.holes_x * k, self.holes_y * k);
        let radius = self.hole_diameter_mm / 2.0;
        let px = self.hole_pitch_mm / k as f64;
        let mut mask = vec![0u8; (w * h) as usize];
        for py in 0..h {
            for pxi in 0..w {
                // Offset of this mask pixel's centre from its hole's centre.
                let ox = ((pxi % k) as f64 + 0.5) * px - self.hole_pitch_mm / 2.0;
                let oy = ((py % k) as f64 + 0.5) * px - self.hole_pitch_mm / 2.0;
                // A hole smaller than a mask pixel still opens the pixel it falls in.
                let open = ox * ox + oy * oy <= radius * radius || (ox.abs() <= px / 2.0 && oy.abs() <= px / 2.0);
                mask[(py * w + pxi) as usize] = if open { 255 } else { 0 };
            }
        }
        (w, h, mask)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_paper_has_the_papers_resolution() {
        for name in PRESETS {
            DisplayGeometry::preset(name).unwrap().validate().unwrap();
        }
        let p = DisplayGeometry::paper();
        assert_eq!(
            (p.holes_x, p.holes_y, p.views_u, p.views_v, p.n_bands()),
            (100, 100, 5, 5, 4)
        );
        // 5 views span 5 × 1.2 mm = 6 mm: several views cross a 6 mm pupil.
        assert!((p.view_spacing_at_pupil_mm() - 1.2).abs() < 1e-9);
    }

    #[test]
    fn sample_index_round_trips() {
        let d = DisplayGeometry::small();
        for idx in [0, 1, 7, 123, d.n_samples_per_band() - 1] {
            let (x, y, i, j) = d.sample_coords(idx);
            assert_eq!(d.sample_index(x, y, i, j), idx);
        }
    }

    #[test]
    fn block_aims_every_hole_at_the_design_eye() {
        // The chief ray from the block centre through any hole reaches the pupil plane on axis.
        let d = DisplayGeometry::paper();
        let (x, y) = (3, 91);
        let h = d.hole_centre_mm(x, y);
        let (cu, cv) = ((d.views_u - 1) / 2, (d.views_v - 1) / 2);
        let q = d.screen_pixel_centre_mm(x, y, cu, cv);
        for a in 0..2 {
            let slope = (h[a] - q[a]) / d.gap_mm;
            let at_pupil = h[a] + d.viewing_distance_mm * slope;
            assert!(at_pupil.abs() < 1e-9, "axis {a}: {at_pupil}");
        }
    }

    #[test]
    fn validation_names_the_field() {
        let mut d = DisplayGeometry::paper();
        d.viewing_distance_mm = 5.0;
        assert!(d.validate().unwrap_err().to_string().contains("viewing_distance_mm"));
        let mut d = DisplayGeometry::paper();
        d.screen_pixel_pitch_mm = 0.2;
        assert!(d.validate().unwrap_err().to_string().contains("screen_pixel_pitch_mm"));
        let mut d = DisplayGeometry::paper();
        d.hole_pitch_mm = f64::NAN;
        assert!(d.validate().unwrap_err().to_string().contains("hole_pitch_mm"));
        assert!(DisplayGeometry::preset("nope").is_err());
    }

    #[test]
    fn barrier_mask_opens_one_spot_per_hole() {
        let d = DisplayGeometry::small();
        let (w, h, m) = d.barrier_mask(5);
        assert_eq!((w, h), (120, 120));
        let open = m.iter().filter(|&&v| v == 255).count();
        assert!(open >= (d.holes_x * d.holes_y) as usize);
        assert!(open < (w * h) as usize / 4);
    }
}
