//! Can a display's views be told apart at the pupil? (docs/design.md §2, "Wave optics".)
//!
//! Views leave each aperture s = p_s·d/g apart at the pupil. Diffraction at an aperture of width A (hole
//! diameter, or lenslet side) spreads each view by an angle of order λ/A, so over the viewing distance d each
//! view's light covers a patch of radius r = k·λ·d/A around its chief ray (k = 1.22 to the Airy pattern's first
//! dark ring for a circular hole, 1 to the first zero of sinc² for a square lenslet). Two views are resolved
//! while their spacing exceeds the spread: M = A·s/(λ·d) ≥ 1. A pupil of diameter D then separates about
//! D / max(s, λd/A) view channels, and never more than the display's views across.

use serde::{Deserialize, Serialize};

use crate::physics::diffraction::AIRY_FIRST_ZERO_X;
use crate::physics::display::{Aperture, DisplayGeometry};

/// Resolvability of one band's views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BandResolvability {
    /// The band's centroid wavelength, nm.
    pub wavelength_nm: f64,
    /// Distance between adjacent views at the pupil, s = p_s·d/g, mm.
    pub view_spacing_mm: f64,
    /// Radius of one view's diffraction spread at the pupil (to the first dark ring or zero), mm.
    pub view_spread_mm: f64,
    /// M = A·s/(λ·d): the views are resolved while it is at least 1.
    pub resolvability: f64,
    /// View channels a 4 mm and a 6 mm pupil separate.
    pub views_resolved: ViewsResolved,
}

/// View channels separated by a pupil of each diameter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ViewsResolved {
    /// Across a 4 mm pupil.
    #[serde(rename = "4mm")]
    pub mm4: u32,
    /// Across a 6 mm pupil.
    #[serde(rename = "6mm")]
    pub mm6: u32,
}

/// Per band, whether the display's views can be told apart at the design pupil.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Resolvability {
    /// One entry per projector band, in band order.
    pub bands: Vec<BandResolvability>,
}

impl Resolvability {
    /// The figures for `display`.
    pub fn of(display: &DisplayGeometry) -> Self {
        let s = display.view_spacing_at_pupil_mm();
        let d = display.viewing_distance_mm;
        let a = display.hole_diameter_mm;
        let spread_factor = match display.aperture {
            Aperture::Pinhole => AIRY_FIRST_ZERO_X / std::f64::consts::PI,
            Aperture::Lenslet => 1.0,
        };
        let bands = display
            .projectors
            .iter()
            .map(|p| {
                let wavelength_nm = p.centroid_nm();
                let lambda_mm = wavelength_nm * 1e-6;
                let cell = (lambda_mm * d / a).max(s);
                let across = |pupil_mm: f64| ((pupil_mm / cell).floor() as u32).clamp(1, display.views_u.max(1));
                BandResolvability {
                    wavelength_nm,
                    view_spacing_mm: s,
                    view_spread_mm: spread_factor * lambda_mm * d / a,
                    resolvability: a * s / (lambda_mm * d),
                    views_resolved: ViewsResolved {
                        mm4: across(4.0),
                        mm6: across(6.0),
                    },
                }
            })
            .collect();
        Self { bands }
    }

    /// True when some band's views are not resolved (M < 1).
    pub fn any_unresolved(&self) -> bool {
        self.bands.iter().any(|b| b.resolvability < 1.0)
    }

    /// A one-line warning naming the worst band, if any band is unresolved.
    pub fn warning(&self) -> Option<String> {
        let worst = self
            .bands
            .iter()
            .min_by(|a, b| a.resolvability.total_cmp(&b.resolvability))?;
        (worst.resolvability < 1.0).then(|| {
            format!(
                "the display's views are not resolved: at {:.0} nm diffraction spreads each view over {:.2} mm at \
                 the pupil against {:.2} mm between views (resolvability M = {:.2} < 1)",
                worst.wavelength_nm, worst.view_spread_mm, worst.view_spacing_mm, worst.resolvability
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_secure_lenslets_resolve_their_views() {
        // By hand: A = 1 mm, s = p_s·d/f = (1/9)·500/92.59 = 0.6 mm, d = 500 mm, so M = A·s/(λd) = 1.2e-3/λ[mm]:
        // 2.67 at 450 nm and 1.88 at 640 nm.
        let d = DisplayGeometry::secure();
        assert!((d.view_spacing_at_pupil_mm() - 0.6).abs() < 1e-9);
        let r = Resolvability::of(&d);
        for b in &r.bands {
            let by_hand = 1.0 * 0.6 / (b.wavelength_nm * 1e-6 * 500.0);
            assert!(
                (b.resolvability - by_hand).abs() < 1e-9 && b.resolvability > 1.8,
                "{b:?}"
            );
        }
        assert!(!r.any_unresolved() && r.warning().is_none());
    }

    #[test]
    fn the_dense_pinholes_do_not_resolve_their_views() {
        // By hand for the dense preset at its 450 nm band: A = 0.033 mm, s = p_s·d/g, d = 500 mm;
        // M = A·s/(λd). Every band is below 1, and the spread at 550 nm is 1.22·λd/A ≈ 10 mm.
        let d = DisplayGeometry::dense();
        let r = Resolvability::of(&d);
        assert_eq!(r.bands.len(), d.n_bands());
        for b in &r.bands {
            let lambda = b.wavelength_nm * 1e-6;
            let m = d.hole_diameter_mm * d.view_spacing_at_pupil_mm() / (lambda * d.viewing_distance_mm);
            assert!((b.resolvability - m).abs() < 1e-12);
            assert!(b.resolvability < 1.0, "{b:?}");
        }
        assert!(r.any_unresolved() && r.warning().is_some());
    }

    #[test]
    fn a_display_with_wide_apertures_resolves_its_views() {
        // A lenslet of 1 mm at 500 mm with views 3 mm apart: M = 1·3/(0.00055·500) ≈ 10.9.
        let mut d = DisplayGeometry::paper();
        d.aperture = Aperture::Lenslet;
        d.hole_pitch_mm = 1.0;
        d.hole_diameter_mm = 1.0;
        d.screen_pixel_pitch_mm = 0.2;
        d.gap_mm = d.viewing_distance_mm * 0.2 / 3.0;
        let r = Resolvability::of(&d);
        for b in &r.bands {
            assert!(b.resolvability > 5.0, "{b:?}");
            assert!((b.view_spacing_mm - 3.0).abs() < 1e-9);
            // 6 mm / 3 mm = 2 channels; 4 mm / 3 mm = 1.
            assert_eq!((b.views_resolved.mm4, b.views_resolved.mm6), (1, 2));
        }
        assert!(r.warning().is_none());
    }

    #[test]
    fn the_lenslet_and_pinhole_presets_resolve_their_views_and_the_paper_preset_does_not() {
        // By hand at 555 nm: lenslet 1 mm · 0.6 mm / (555e-6 · 500) = 2.16; pinhole 0.15 · 2.5 / 0.2775 = 1.35;
        // paper 0.08 · 1.2 / 0.2775 = 0.35. The red band (the longest wavelength) is the lowest.
        for (d, low, high) in [
            (DisplayGeometry::lenslet(), 1.5, 3.0),
            (DisplayGeometry::pinhole(), 1.0, 2.0),
            (DisplayGeometry::paper(), 0.2, 0.5),
        ] {
            let r = Resolvability::of(&d);
            for b in &r.bands {
                assert!(b.resolvability > low && b.resolvability < high, "{b:?}");
            }
            assert_eq!(r.any_unresolved(), high < 1.0);
        }
        // 4 mm / 0.6 mm = 6 views across a 4 mm pupil on the lenslet display; 6 mm / 0.6 mm = 10, more than
        // the display's 9.
        let b = &Resolvability::of(&DisplayGeometry::lenslet()).bands[1];
        assert_eq!((b.views_resolved.mm4, b.views_resolved.mm6), (6, 9));
    }

    #[test]
    fn the_json_has_the_documented_shape() {
        let r = Resolvability::of(&DisplayGeometry::paper());
        let v = serde_json::to_value(&r).unwrap();
        let b = &v["bands"][0];
        for key in ["wavelength_nm", "view_spacing_mm", "view_spread_mm", "resolvability"] {
            assert!(b[key].is_number(), "{key}");
        }
        assert!(b["views_resolved"]["4mm"].is_u64() && b["views_resolved"]["6mm"].is_u64());
    }
}
