//! Bystanders anywhere (docs/design.md §4, "who is looked at", (b)): people and cameras beside, above, nearer
//! and farther than the target's eye, each seen through the any-position model (every aperture shows such an
//! eye whatever screen point lies behind it on its line of sight: pixels of neighbouring blocks, the gaps, the
//! periodic repeats of the fans).
//!
//! A bystander's view is a copy of the document shifted (and, nearer or farther, magnified or shrunk) by the
//! blocks its line of sight crosses. The attacker knows the display's geometry and where they stand, so each
//! view is judged twice: as seen, and resampled back onto the document's layout ([`unwarp`]); the better
//! judgement counts.

use serde::{Deserialize, Serialize};

use crate::physics::display::DisplayGeometry;
use crate::physics::transport::{EyePosition, RetinalGrid};

/// Where bystanders stand and who they are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct BystanderOptions {
    /// Offsets from the target's pupil at the design distance, mm; each is looked at to the right, left, above
    /// and below.
    pub lateral_mm: Vec<f64>,
    /// Other viewing distances (mm from the barrier): nearer and farther than the target.
    pub distances_mm: Vec<f64>,
    /// Offsets to the right looked at at each of those distances, mm (0 = straight in front of or behind the
    /// target).
    pub lateral_at_distance_mm: Vec<f64>,
    /// People sampled at every position.
    pub people: u32,
    /// Focus errors the camera sweeps at every position, dioptres off the display.
    pub camera_focus_d: Vec<f64>,
    /// Camera apertures tried at every position, mm.
    pub camera_apertures_mm: Vec<f64>,
}

impl Default for BystanderOptions {
    fn default() -> Self {
        Self {
            lateral_mm: vec![10.0, 20.0, 50.0, 100.0, 200.0, 500.0],
            distances_mm: vec![300.0, 400.0, 700.0, 1000.0, 1500.0],
            lateral_at_distance_mm: vec![0.0, 50.0, 200.0],
            people: 6,
            camera_focus_d: vec![-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 3.0],
            camera_apertures_mm: vec![2.0, 4.0, 8.0],
        }
    }
}

impl BystanderOptions {
    /// Every bystander position, as an eye position relative to the target's (the design position).
    pub fn positions(&self, display: &DisplayGeometry) -> Vec<EyePosition> {
        let mut out = Vec::new();
        for &r in &self.lateral_mm {
            for (x_mm, y_mm) in [(r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)] {
                out.push(EyePosition { x_mm, y_mm, dz_mm: 0.0 });
            }
        }
        for &d in &self.distances_mm {
            for &x_mm in &self.lateral_at_distance_mm {
                out.push(EyePosition {
                    x_mm,
                    y_mm: 0.0,
                    dz_mm: d - display.viewing_distance_mm,
                });
            }
        }
        // The target's own position is not a bystander's (a distance list may hold the design distance).
        out.retain(|e| e.x_mm != 0.0 || e.y_mm != 0.0 || e.dz_mm != 0.0);
        out
    }

    /// Checks the ranges: positions 0–2,000 mm off, distances 100–5,000 mm, at most 64 positions, 32 people,
    /// focus within ±10 D, apertures 0.5–25 mm.
    pub fn validate(&self) -> Result<(), String> {
        let finite_in = |v: &[f64], lo: f64, hi: f64| v.iter().all(|x| x.is_finite() && *x >= lo && *x <= hi);
        if !finite_in(&self.lateral_mm, 0.0, 2000.0) || !finite_in(&self.lateral_at_distance_mm, 0.0, 2000.0) {
            return Err("lateral offsets must be within 0..=2000 mm".into());
        }
        if !finite_in(&self.distances_mm, 100.0, 5000.0) {
            return Err("distances must be within 100..=5000 mm".into());
        }
        let n = 4 * self.lateral_mm.len() + self.distances_mm.len() * self.lateral_at_distance_mm.len();
        if n > 64 {
            return Err(format!("at most 64 positions, got {n}"));
        }
        if self.people > 32 {
            return Err(format!("at most 32 people per position, got {}", self.people));
        }
        if !finite_in(&self.camera_focus_d, -10.0, 10.0) || self.camera_focus_d.len() > 32 {
            return Err("at most 32 camera focus errors within ±10 D".into());
        }
        if !finite_in(&self.camera_apertures_mm, 0.5, 25.0) || self.camera_apertures_mm.len() > 8 {
            return Err("at most 8 camera apertures within 0.5..=25 mm".into());
        }
        Ok(())
    }
}

/// What was seen from one bystander position.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BystanderPosition {
    /// Where, relative to the target's eye.
    pub eye: EyePosition,
    /// Distance from the target's pupil, mm.
    pub distance_mm: f64,
    /// Light reaching this position relative to the target's (mean luminance of the view over the target's).
    pub relative_light: f64,
    /// The most legible sampled person's view.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_person: Option<super::ViewScore>,
    /// People who read.
    pub people_read: u32,
    /// People sampled here.
    pub people: u32,
    /// The camera's best setting (focus, aperture, channel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_camera: Option<super::ViewScore>,
    /// Camera settings that read.
    pub camera_settings_read: u32,
    /// Camera settings tried.
    pub camera_settings: u32,
    /// The settings that read (focus, aperture, channel, then the view's legibility and the known-font attacker's
    /// margin: how far its weakest character's right glyph led the best wrong one), in the sweep's order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera_settings_that_read: Vec<String>,
    /// The camera attacker's own pick: trying the known-font readings of every setting here (as seen and
    /// unwarped), most confident first and each PIN once, how many guesses until the right one
    /// ([`guesses_to_read`]; none when no setting reads). 1: the attacker can tell which setting reads.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_guesses_to_read: Option<u32>,
}

/// How many distinct texts an attacker who tries `readings` (confidence, text read, whether it is right) in order of
/// falling confidence tries until the right one; `None` when no reading is right. The known-font attacker's
/// confidence (its mean winning correlation, `KnownFontRead::confidence`) is the only thing it ranks by: it does
/// not know which reading is right.
pub fn guesses_to_read(readings: &[(f64, String, bool)]) -> Option<u32> {
    let mut order: Vec<&(f64, String, bool)> = readings.iter().collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut tried: Vec<&str> = Vec::new();
    for (_, text, right) in order {
        if !tried.contains(&text.as_str()) {
            tried.push(text);
        }
        if *right {
            return Some(tried.len() as u32);
        }
    }
    None
}

/// Everybody who looked from elsewhere.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BystanderSummary {
    /// Every position.
    pub positions: Vec<BystanderPosition>,
    /// The smallest distance from the target's pupil at which a person or camera read (None: nobody did).
    pub nearest_reader_mm: Option<f64>,
    /// The smallest distance looked at where nobody read, mm.
    pub nearest_position_mm: f64,
}

impl BystanderSummary {
    /// The summary of `positions`.
    pub fn from_positions(positions: Vec<BystanderPosition>) -> Self {
        let read = |p: &&BystanderPosition| p.people_read > 0 || p.camera_settings_read > 0;
        let nearest_reader_mm = positions
            .iter()
            .filter(read)
            .map(|p| p.distance_mm)
            .min_by(f64::total_cmp);
        let nearest_position_mm = positions
            .iter()
            .map(|p| p.distance_mm)
            .min_by(f64::total_cmp)
            .unwrap_or(f64::INFINITY);
        Self {
            positions,
            nearest_reader_mm,
            nearest_position_mm,
        }
    }
}

/// Resamples the view of an eye at `eye` back onto the document's layout: through the aperture at barrier
/// position h such an eye sees block (h(1 + g/d') − e·g/d')/(p_h(1 + g/d)) (`transport::block_seen`, without
/// its rounding), which carries the document's pixel at that block. So the document pixel at x appears at
/// h = (x(1 + g/d) + e·g/d')/(1 + g/d'); the view is sampled there (bilinearly; outside the view, its mean).
/// At the design position this is the identity.
pub fn unwarp(view: &[f32], grid: &RetinalGrid, display: &DisplayGeometry, eye: EyePosition) -> Vec<f32> {
    let (w, h) = (grid.width as usize, grid.height as usize);
    let g = display.gap_mm;
    let d_eye = display.viewing_distance_mm + eye.dz_mm;
    let (aim, aim_eye) = (1.0 + g / display.viewing_distance_mm, 1.0 + g / d_eye);
    let mean = view.iter().map(|v| *v as f64).sum::<f64>() / view.len().max(1) as f64;
    // Grid pixel coordinate of the barrier position where document position (pixel coordinate) c appears.
    let seen_at = |c: f64, origin: f64, e: f64| -> f64 {
        let x = origin + c * grid.pixel_mm;
        let hx = (x * aim + e * g / d_eye) / aim_eye;
        (hx - origin) / grid.pixel_mm
    };
    let xs: Vec<f64> = (0..w).map(|i| seen_at(i as f64, grid.origin_mm[0], eye.x_mm)).collect();
    let ys: Vec<f64> = (0..h).map(|j| seen_at(j as f64, grid.origin_mm[1], eye.y_mm)).collect();
    let mut out = Vec::with_capacity(w * h);
    for &y in &ys {
        for &x in &xs {
            out.push(bilinear(view, w, h, x, y).unwrap_or(mean) as f32);
        }
    }
    out
}

/// Bilinear sample of `img` at pixel coordinates (x, y); `None` outside.
fn bilinear(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<f64> {
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |xx: usize, yy: usize| img[yy * w + xx] as f64;
    Some((1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x1, y0)) + fy * ((1.0 - fx) * at(x0, y1) + fx * at(x1, y1)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::transport::block_seen;

    #[test]
    fn the_camera_attacker_tries_distinct_readings_most_confident_first() {
        let r = |c: f64, t: &str, right: bool| (c, t.to_string(), right);
        // Confidence order: 0.9 "1111", 0.8 "1111" (the same guess again), 0.7 "4821" (right): the second guess.
        let readings = vec![r(0.7, "4821", true), r(0.9, "1111", false), r(0.8, "1111", false)];
        assert_eq!(guesses_to_read(&readings), Some(2));
        // A right reading at the top is the first guess; a less confident right one changes nothing.
        let readings = vec![r(0.95, "4821", true), r(0.9, "1111", false), r(0.1, "4821", true)];
        assert_eq!(guesses_to_read(&readings), Some(1));
        // Below three wrong PINs: the fourth guess.
        let readings = vec![
            r(0.2, "4821", true),
            r(0.5, "1", false),
            r(0.4, "2", false),
            r(0.3, "3", false),
        ];
        assert_eq!(guesses_to_read(&readings), Some(4));
        // Nothing right, or nothing at all: no number of guesses.
        assert_eq!(guesses_to_read(&[r(0.5, "1111", false)]), None);
        assert_eq!(guesses_to_read(&[]), None);
    }

    #[test]
    fn the_default_grid_spans_10_to_500_mm_and_300_to_1500_mm() {
        let d = DisplayGeometry::lenslet();
        let o = BystanderOptions::default();
        o.validate().unwrap();
        let p = o.positions(&d);
        assert_eq!(p.len(), 24 + 15);
        let dist: Vec<f64> = p
            .iter()
            .map(|e| (e.x_mm.powi(2) + e.y_mm.powi(2) + e.dz_mm.powi(2)).sqrt())
            .collect();
        assert_eq!(dist.iter().copied().fold(f64::INFINITY, f64::min), 10.0);
        assert!(p.iter().any(|e| e.dz_mm == -200.0) && p.iter().any(|e| e.dz_mm == 1000.0));
        let bad = BystanderOptions {
            distances_mm: vec![50.0],
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        // The design distance in the list adds its lateral positions but not the target's own.
        let with_design = BystanderOptions {
            distances_mm: vec![500.0],
            ..Default::default()
        };
        assert_eq!(with_design.positions(&d).len(), 24 + 2);
    }

    #[test]
    fn unwarp_undoes_the_shift_of_the_blocks_a_bystander_sees() {
        // A view that is the document moved by the blocks each aperture shows (block_seen, the independent
        // closed form with rounding) comes back to the document wherever the blocks are whole: at the design
        // distance the shift is whole blocks and unwarp returns the document exactly inside the frame.
        let d = DisplayGeometry {
            holes_x: 40,
            holes_y: 30,
            ..DisplayGeometry::lenslet()
        };
        let grid = RetinalGrid::for_display(&d, 1);
        let (w, h) = (grid.width as usize, grid.height as usize);
        let doc: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 13) as f32).collect();
        let per_block = d.block_shift_at_pupil_mm(d.viewing_distance_mm);
        let eye = EyePosition {
            x_mm: 2.0 * per_block,
            y_mm: -per_block,
            dz_mm: 0.0,
        };
        let view: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let k = block_seen(
                    &d,
                    d.viewing_distance_mm,
                    [eye.x_mm, eye.y_mm],
                    d.hole_centre_mm(x as u32, y as u32),
                );
                let (bx, by) = (x as i64 + k[0], y as i64 + k[1]);
                if (0..w as i64).contains(&bx) && (0..h as i64).contains(&by) {
                    doc[by as usize * w + bx as usize]
                } else {
                    0.0
                }
            })
            .collect();
        let back = unwarp(&view, &grid, &d, eye);
        for y in 2..h - 2 {
            for x in 3..w - 3 {
                assert!((back[y * w + x] - doc[y * w + x]).abs() < 1e-4, "({x}, {y})");
            }
        }
        // Nearer than the design distance the blocks seen drift across the display (the view is magnified);
        // unwarp's continuous mapping brings a smooth document back where the rounded blocks carry it.
        let near = EyePosition {
            x_mm: 20.0,
            y_mm: 0.0,
            dz_mm: -200.0,
        };
        let smooth: Vec<f32> = (0..w * h)
            .map(|i| ((i % w) as f32 * 0.3).sin() + ((i / w) as f32 * 0.25).cos())
            .collect();
        let seen: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let k = block_seen(&d, 300.0, [near.x_mm, near.y_mm], d.hole_centre_mm(x as u32, y as u32));
                let (bx, by) = (
                    (x as i64 + k[0]).clamp(0, w as i64 - 1),
                    (y as i64 + k[1]).clamp(0, h as i64 - 1),
                );
                smooth[by as usize * w + bx as usize]
            })
            .collect();
        let back = unwarp(&seen, &grid, &d, near);
        let inner = |v: &[f32]| -> Vec<f32> {
            (4..h - 4)
                .flat_map(|y| (8..w - 8).map(move |x| (x, y)))
                .map(|(x, y)| v[y * w + x])
                .collect()
        };
        let restored = crate::evaluation::ncc(&inner(&back), &inner(&smooth));
        let raw = crate::evaluation::ncc(&inner(&seen), &inner(&smooth));
        assert!(restored > 0.95 && raw < 0.8, "restored {restored}, raw {raw}");
        // The design position is the identity.
        let same = unwarp(&doc, &grid, &d, EyePosition::default());
        assert!(same.iter().zip(&doc).all(|(a, b)| (a - b).abs() < 1e-3));
    }
}
