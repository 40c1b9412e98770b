//! Head tracking on the display side: frames re-indexed for the eye position a tracker reports
//! (`eyekey_core::physics::tracking::retarget`), so a target who moves sideways keeps reading without a new
//! encode. A rig does this for every tracker update; `eyekey display track` does it once, from an installed
//! bundle to a new one.

use std::path::Path;

use anyhow::{bail, Context, Result};
use eyekey_core::bundle::{read_verified_bundle, write_bundle};
use eyekey_core::physics::tracking::{retarget, view_shift};
use eyekey_core::physics::transport::EyePosition;

/// How far a tracked eye may be from the design position, mm: beyond it the frames are for someone else's seat.
pub const MAX_TRACKED_OFFSET_MM: f64 = 50.0;

/// Writes into `out` (a new directory) the bundle at `bundle` re-indexed for an eye at (`x_mm`, `y_mm`) from the
/// design position, at the design distance; returns the view shift (views in u and v) the frames moved by.
pub fn track_bundle(bundle: &Path, x_mm: f64, y_mm: f64, out: &Path) -> Result<(i64, i64)> {
    if !(x_mm.is_finite() && y_mm.is_finite()) || x_mm.hypot(y_mm) > MAX_TRACKED_OFFSET_MM {
        bail!(
            "the tracked eye must be within {MAX_TRACKED_OFFSET_MM} mm of the design position, got ({x_mm}, {y_mm}) mm"
        );
    }
    let b = read_verified_bundle(bundle).with_context(|| format!("reading {}", bundle.display()))?;
    let display = &b.manifest.display;
    let eye = EyePosition { x_mm, y_mm, dz_mm: 0.0 };
    let l = retarget(display, &b.light_field, eye);
    write_bundle(out, display, &l, &[], b.manifest.barrier_mask_pixels_per_hole)
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(view_shift(display, eye))
}

#[cfg(test)]
mod tests {
    use super::*;
    use eyekey_core::physics::display::DisplayGeometry;

    #[test]
    fn a_tracked_bundle_holds_the_retargeted_frames_and_refuses_a_far_eye() {
        let display = DisplayGeometry {
            holes_x: 8,
            holes_y: 6,
            ..DisplayGeometry::lenslet()
        };
        let n = display.n_samples_per_band() * display.n_bands();
        let l: Vec<f32> = (0..n).map(|i| ((i * 37) % 101) as f32 / 100.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let src = dir.path().join("src");
        write_bundle(&src, &display, &l, &[], 4).unwrap();
        let out = dir.path().join("tracked");
        assert_eq!(track_bundle(&src, 1.8, -0.6, &out).unwrap(), (3, -1));
        let (_, back) = eyekey_core::bundle::read_bundle(&out).unwrap();
        // Frames are 16-bit PNGs: the round trip is exact to 1/65535 of L_max.
        let want = retarget(
            &display,
            &read_verified_bundle(&src).unwrap().light_field,
            EyePosition {
                x_mm: 1.8,
                y_mm: -0.6,
                dz_mm: 0.0,
            },
        );
        assert!(back.iter().zip(&want).all(|(a, b)| (a - b).abs() < 2e-5));
        assert!(back != read_verified_bundle(&src).unwrap().light_field);
        assert!(track_bundle(&src, 60.0, 0.0, &dir.path().join("far")).is_err());
    }
}
