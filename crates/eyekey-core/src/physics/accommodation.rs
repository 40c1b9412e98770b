//! Eyes that focus: the range of focus a viewer can hold while looking at the display (docs/design.md §4).
//!
//! A profile states the eye's wavefront at one state of accommodation. A person who wants to read what is not
//! meant for them can change it: accommodating adds power to the eye (focus nearer), relaxing removes it (focus
//! farther). Adding power `a` dioptres to the eye is, for the light reaching the retina, the same as a spectacle
//! sphere `−a` dioptres stronger in front of it, so the eye accommodated by `a` is
//! [`VisionProfile::refocused`]`(−a)` (a sphere of −2 D is the myopic c₂⁰ = +2.598 µm at 6 mm, ANSI Z80.28; an
//! accommodating eye grows more myopic).
//!
//! How far an eye can accommodate falls with age. Hofstetter's (1950) lines through Duane's (1922) measurements
//! give the maximum amplitude as 25 − 0.4·age dioptres (the mean 18.5 − 0.3·age, the minimum 15 − 0.25·age); the
//! judge takes the maximum, the viewer most able to refocus at that age.

use serde::{Deserialize, Serialize};

use crate::physics::profile::{ProfileError, VisionProfile};

/// Hofstetter's (1950) maximum amplitude of accommodation at `age_years`, dioptres: 25 − 0.4·age, never below 0.
pub fn max_amplitude_d(age_years: f64) -> f64 {
    (25.0 - 0.4 * age_years).max(0.0)
}

/// The focus range every accommodating viewer is judged over: from `relax_d` dioptres less power than the
/// profile states to `accommodate_d` more, in `step_d` steps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct Accommodation {
    /// Dioptres of power the eye may give up below its profile's focus (focusing farther), 0–3.
    pub relax_d: f64,
    /// Dioptres of power the eye may add above its profile's focus (focusing nearer), 0–10; an older eye's is at
    /// most its [`max_amplitude_d`].
    pub accommodate_d: f64,
    /// Step between the focus states judged, dioptres (0.05–1).
    pub step_d: f64,
}

impl Default for Accommodation {
    /// −1 to +2 D around the profile's focus in 0.25 D steps: 13 focus states.
    fn default() -> Self {
        Self {
            relax_d: 1.0,
            accommodate_d: 2.0,
            step_d: 0.25,
        }
    }
}

impl Accommodation {
    /// No refocusing: every viewer holds the focus their profile states.
    pub fn fixed() -> Self {
        Self {
            relax_d: 0.0,
            accommodate_d: 0.0,
            step_d: 0.25,
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), String> {
        let within = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
        if !within(self.relax_d, 0.0, 3.0) {
            return Err(format!("relax_d must be within 0..=3 D, got {}", self.relax_d));
        }
        if !within(self.accommodate_d, 0.0, 10.0) {
            return Err(format!(
                "accommodate_d must be within 0..=10 D, got {}",
                self.accommodate_d
            ));
        }
        if !within(self.step_d, 0.05, 1.0) {
            return Err(format!("step_d must be within 0.05..=1 D, got {}", self.step_d));
        }
        Ok(())
    }

    /// The accommodation states (dioptres of power added to the profile's eye; + nearer) `profile` is judged in:
    /// its own focus first, then ever farther from it, the nearer side first at each distance. The nearer side
    /// stops at `accommodate_d` or at the profile's age's [`max_amplitude_d`], whichever is less.
    pub fn states(&self, profile: &VisionProfile) -> Vec<f64> {
        let near = match profile.age_years {
            Some(age) => self.accommodate_d.min(max_amplitude_d(age)),
            None => self.accommodate_d,
        };
        let step = self.step_d.max(0.05);
        // A state within a hundredth of a step of the end is kept (0.25·8 is 2.0 to rounding).
        let steps = |range: f64| (range / step + 0.01).floor().max(0.0) as usize;
        let (up, down) = (steps(near), steps(self.relax_d));
        let mut out = vec![0.0];
        for k in 1..=up.max(down) {
            if k <= up {
                out.push(k as f64 * step);
            }
            if k <= down {
                out.push(-(k as f64) * step);
            }
        }
        out
    }

    /// `profile`'s eye accommodated by `a` dioptres (+ nearer): its sphere `a` dioptres more negative.
    pub fn accommodated(profile: &VisionProfile, a: f64) -> VisionProfile {
        if a == 0.0 {
            profile.clone()
        } else {
            profile.refocused(-a)
        }
    }

    /// `person` accommodated, within this range, to the focus that brings their spherical equivalent nearest
    /// `target`'s ([`spherical_equivalent_d`]): the focus a person who wants to read the target's frames would
    /// look for first, since defocus is most of what tells two people's eyes apart. Returns the eye and the
    /// accommodation, dioptres.
    pub fn matching(
        &self,
        person: &VisionProfile,
        target: &VisionProfile,
    ) -> Result<(VisionProfile, f64), ProfileError> {
        let states = self.states(person);
        let (lo, hi) = states.iter().fold((0f64, 0f64), |(l, h), s| (l.min(*s), h.max(*s)));
        // Accommodating by a makes the eye's spherical equivalent a dioptres more negative.
        let a = (spherical_equivalent_d(person)? - spherical_equivalent_d(target)?).clamp(lo, hi);
        Ok((Self::accommodated(person, a), a))
    }
}

/// The spherical equivalent of the eye's wavefront at its viewing pupil (prescription included), in the form a
/// correcting prescription takes: M = −4√3·c₂⁰/r², r the pupil radius in mm and c₂⁰ in µm (Thibos, Hong, Bradley
/// & Applegate 2004, J. Vision 4(4):9, eq. 2; ANSI Z80.28). A myopic eye's is negative.
pub fn spherical_equivalent_d(profile: &VisionProfile) -> Result<f64, ProfileError> {
    let w = profile.effective_wavefront()?;
    let r = profile.pupil_diameter_mm / 2.0;
    Ok(-4.0 * 3f64.sqrt() * w.get(4) / (r * r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_range_is_thirteen_states_from_one_dioptre_farther_to_two_nearer_own_focus_first() {
        let states = Accommodation::default().states(&VisionProfile::perfect());
        assert_eq!(states.len(), 13);
        assert_eq!(&states[..5], &[0.0, 0.25, -0.25, 0.5, -0.5]);
        let (lo, hi) = states.iter().fold((0f64, 0f64), |(l, h), s| (l.min(*s), h.max(*s)));
        assert_eq!((lo, hi), (-1.0, 2.0));
        assert_eq!(Accommodation::fixed().states(&VisionProfile::perfect()), vec![0.0]);
    }

    #[test]
    fn age_narrows_the_nearer_side_by_hofstetters_maximum_amplitude() {
        // Hofstetter's maximum: 25 − 0.4·age, so 9 D at 40, 1 D at 60, none from 62.5.
        assert!((max_amplitude_d(40.0) - 9.0).abs() < 1e-12);
        assert!((max_amplitude_d(60.0) - 1.0).abs() < 1e-12);
        assert_eq!(max_amplitude_d(70.0), 0.0);
        let aged = |age| VisionProfile {
            age_years: Some(age),
            ..VisionProfile::perfect()
        };
        let range = Accommodation::default();
        assert_eq!(range.states(&aged(40.0)).len(), 13);
        let sixty = range.states(&aged(60.0));
        assert_eq!(sixty.iter().cloned().fold(f64::MIN, f64::max), 1.0);
        assert_eq!(sixty.len(), 9);
        // The relaxing side does not depend on age.
        assert_eq!(range.states(&aged(70.0)), vec![0.0, -0.25, -0.5, -0.75, -1.0]);
    }

    #[test]
    fn an_accommodating_eye_grows_more_myopic_by_the_power_it_adds() {
        // +1 D of accommodation at a 6 mm pupil adds the defocus of a −1 D sphere: c₂⁰ = 1·9/(4√3) = 1.299 µm.
        let p = VisionProfile::perfect();
        let c20 = |q: &VisionProfile| q.effective_wavefront().unwrap().get(4);
        let near = Accommodation::accommodated(&p, 1.0);
        assert!((c20(&near) - c20(&p) - 9.0 / (4.0 * 3f64.sqrt())).abs() < 1e-9);
        assert_eq!(Accommodation::accommodated(&p, 0.0), p);
    }

    #[test]
    fn a_person_refocusing_to_read_matches_the_targets_spherical_equivalent_within_reach() {
        let eye = |sphere_d: f64, pupil: f64| VisionProfile {
            pupil_diameter_mm: pupil,
            prescription: Some(crate::physics::zernike::Prescription {
                sphere_d,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            }),
            ..VisionProfile::perfect()
        };
        // A −2 D sphere is M = −2 D at any pupil (c₂⁰ = 2·r²/(4√3): 2.598 µm at 6 mm, 1.155 µm at 4 mm).
        assert!((spherical_equivalent_d(&eye(-2.0, 6.0)).unwrap() + 2.0).abs() < 1e-9);
        assert!((spherical_equivalent_d(&eye(-2.0, 4.0)).unwrap() + 2.0).abs() < 1e-9);
        let range = Accommodation::default();
        // A +1.5 D (far-sighted) person meets a −0.5 D target by accommodating 2 D, the range's end.
        let target = eye(-0.5, 5.0);
        let (p, a) = range.matching(&eye(1.5, 4.0), &target).unwrap();
        assert!((a - 2.0).abs() < 1e-9);
        assert!((spherical_equivalent_d(&p).unwrap() + 0.5).abs() < 1e-9);
        // A +3 D person can only get to +1 D; a −1.2 D one relaxes 0.7 D.
        assert!((range.matching(&eye(3.0, 4.0), &target).unwrap().1 - 2.0).abs() < 1e-9);
        assert!((range.matching(&eye(-1.2, 4.0), &target).unwrap().1 + 0.7).abs() < 1e-9);
        // A −3 D person can relax only 1 D.
        assert!((range.matching(&eye(-3.0, 4.0), &target).unwrap().1 + 1.0).abs() < 1e-9);
    }

    #[test]
    fn ranges_outside_an_eyes_reach_are_refused() {
        assert!(Accommodation::default().validate().is_ok());
        for bad in [
            Accommodation {
                relax_d: -1.0,
                ..Default::default()
            },
            Accommodation {
                accommodate_d: f64::NAN,
                ..Default::default()
            },
            Accommodation {
                step_d: 0.0,
                ..Default::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
