//! A person's vision profile: the key that decodes an eyekey light field.
//!
//! Optical part: Zernike wavefront (OSA/ANSI Z80.28, µm at a stated pupil) and an optional spectacle
//! prescription; spectral part: the CIE 2006 / Asano 2016 individual-observer parameters or a sampled LMS table.

use serde::{Deserialize, Serialize};

use crate::physics::spectral::{ConeFundamentals, SpectralSensitivity};
use crate::physics::zernike::{Prescription, ZernikeCoefficients};

/// Errors in a vision profile; every message names the field.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ProfileError {
    /// A field is outside its physical range or malformed.
    #[error("{field}: {reason}")]
    Invalid {
        /// Dotted path of the field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// The JSON could not be parsed.
    #[error("profile JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// Largest accepted |Zernike coefficient|, µm. Uncorrected eyes reach a few µm of defocus; 20 µm is far
/// beyond any eye an aberrometer measures, and rejects mm-for-µm unit mistakes.
pub const MAX_COEFFICIENT_UM: f64 = 20.0;

/// One person's vision profile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct VisionProfile {
    /// Entrance-pupil diameter while viewing the display, mm (2–9).
    #[cfg_attr(feature = "openapi", schema(minimum = 2.0, maximum = 9.0))]
    pub pupil_diameter_mm: f64,
    /// OSA/ANSI Zernike coefficients, µm, index j = (n(n+2)+m)/2, stated for `zernike_pupil_diameter_mm`; at
    /// most 66 terms (order 10), each within ±20 µm.
    #[cfg_attr(feature = "openapi", schema(max_items = 66, value_type = Vec<ZernikeTerm>))]
    pub zernike_um: Vec<f64>,
    /// Pupil diameter the coefficients were measured at, mm (2–10, at least `pupil_diameter_mm`); defaults to
    /// `pupil_diameter_mm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "openapi", schema(minimum = 2.0, maximum = 10.0))]
    pub zernike_pupil_diameter_mm: Option<f64>,
    /// Refractive error in prescription form (sphere/cylinder/axis, as an optometrist writes it), not
    /// corrected while viewing: its C(2,0) and C(2,±2) add to the Zernike terms.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prescription: Option<Prescription>,
    /// Cone spectral sensitivities.
    #[serde(default)]
    pub spectral: SpectralSensitivity,
    /// Wavelength the aberrations were measured at, nm (400–1000); defaults to 555. Under wave optics each band
    /// adds the eye's chromatic defocus relative to it (Thibos et al. 1992).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "openapi", schema(minimum = 400.0, maximum = 1000.0))]
    pub reference_wavelength_nm: Option<f64>,
    /// Age in years (0–120), when known: it narrows how far the eye can accommodate
    /// ([`Accommodation`](crate::physics::accommodation::Accommodation)), so the evaluation judges an older
    /// viewer over fewer focus states. Unknown: the young eye's full range.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "openapi", schema(minimum = 0.0, maximum = 120.0))]
    pub age_years: Option<f64>,
}

/// One Zernike coefficient, µm (the schema of an item of `zernike_um`).
#[cfg(feature = "openapi")]
pub struct ZernikeTerm(pub f64);

#[cfg(feature = "openapi")]
impl utoipa::PartialSchema for ZernikeTerm {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        utoipa::openapi::ObjectBuilder::new()
            .schema_type(utoipa::openapi::schema::Type::Number)
            .format(Some(utoipa::openapi::SchemaFormat::KnownFormat(
                utoipa::openapi::KnownFormat::Double,
            )))
            .minimum(Some(-MAX_COEFFICIENT_UM))
            .maximum(Some(MAX_COEFFICIENT_UM))
            .description(Some("A Zernike coefficient, µm"))
            .into()
    }
}

#[cfg(feature = "openapi")]
impl utoipa::ToSchema for ZernikeTerm {}

impl VisionProfile {
    /// A perfect eye with the standard observer's cones and a 6 mm pupil.
    pub fn perfect() -> Self {
        Self {
            pupil_diameter_mm: 6.0,
            zernike_um: vec![0.0; 28],
            zernike_pupil_diameter_mm: None,
            prescription: None,
            spectral: SpectralSensitivity::default(),
            reference_wavelength_nm: None,
            age_years: None,
        }
    }

    /// Parses and validates a profile from JSON.
    pub fn from_json(text: &str) -> Result<Self, ProfileError> {
        let p: Self = serde_json::from_str(text)?;
        p.validate()?;
        Ok(p)
    }

    /// Checks finiteness and physical ranges.
    pub fn validate(&self) -> Result<(), ProfileError> {
        let bad = |field: &str, reason: String| ProfileError::Invalid {
            field: field.to_string(),
            reason,
        };
        if !(self.pupil_diameter_mm.is_finite() && (2.0..=9.0).contains(&self.pupil_diameter_mm)) {
            return Err(bad(
                "pupil_diameter_mm",
                format!("must be within 2..=9 mm, got {}", self.pupil_diameter_mm),
            ));
        }
        if let Some(w) = self.reference_wavelength_nm {
            if !(w.is_finite() && (400.0..=1000.0).contains(&w)) {
                return Err(bad(
                    "reference_wavelength_nm",
                    format!("must be within 400..=1000 nm, got {w}"),
                ));
            }
        }
        if let Some(a) = self.age_years {
            if !(a.is_finite() && (0.0..=120.0).contains(&a)) {
                return Err(bad("age_years", format!("must be within 0..=120 years, got {a}")));
            }
        }
        if let Some(z) = self.zernike_pupil_diameter_mm {
            if !(z.is_finite() && (2.0..=10.0).contains(&z)) {
                return Err(bad(
                    "zernike_pupil_diameter_mm",
                    format!("must be within 2..=10 mm, got {z}"),
                ));
            }
            if z + 1e-9 < self.pupil_diameter_mm {
                return Err(bad(
                    "zernike_pupil_diameter_mm",
                    format!(
                        "coefficients measured at {z} mm cannot describe a larger {} mm pupil",
                        self.pupil_diameter_mm
                    ),
                ));
            }
        }
        if self.zernike_um.len() > 66 {
            return Err(bad(
                "zernike_um",
                format!("at most 66 terms (order 10), got {}", self.zernike_um.len()),
            ));
        }
        for (j, c) in self.zernike_um.iter().enumerate() {
            if !c.is_finite() || c.abs() > MAX_COEFFICIENT_UM {
                return Err(bad(
                    &format!("zernike_um[{j}]"),
                    format!("must be finite with |c| ≤ {MAX_COEFFICIENT_UM} µm, got {c}"),
                ));
            }
        }
        if let Some(p) = &self.prescription {
            p.validate().map_err(|e| bad("prescription", e.to_string()))?;
        }
        self.spectral.validate().map_err(|e| bad("spectral", e.to_string()))?;
        Ok(())
    }

    /// The same eye focused `dd` dioptres away: `dd` added to its prescription's sphere (an eye without one gets
    /// a pure sphere), as an eye's accommodation drifts while it looks.
    pub fn refocused(&self, dd: f64) -> Self {
        let mut p = self.prescription.unwrap_or(Prescription {
            sphere_d: 0.0,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        });
        p.sphere_d += dd;
        Self {
            prescription: Some(p),
            ..self.clone()
        }
    }

    /// The same eye with its viewing pupil `dp` mm wider (narrower when negative), as a pupil follows the light
    /// while one looks: the coefficients stay stated for the pupil they were measured at and are rescaled to the
    /// new one (ISO 24157 Annex B). Nothing is known of the eye outside the measured pupil, so the pupil grows at
    /// most to it (and shrinks at least to 2 mm, the profile's lower bound).
    pub fn with_pupil_changed(&self, dp: f64) -> Self {
        let measured = self.zernike_pupil_diameter_mm.unwrap_or(self.pupil_diameter_mm);
        Self {
            pupil_diameter_mm: (self.pupil_diameter_mm + dp).clamp(2.0, measured.max(2.0)),
            zernike_pupil_diameter_mm: Some(measured),
            ..self.clone()
        }
    }

    /// The wavefront the display meets: coefficients rescaled to the viewing pupil (ISO 24157 Annex B), with
    /// the prescription's defocus and astigmatism added, piston and tilt removed (tilt only shifts the
    /// whole retinal image).
    pub fn effective_wavefront(&self) -> Result<ZernikeCoefficients, ProfileError> {
        let bad = |reason: String| ProfileError::Invalid {
            field: "zernike_um".into(),
            reason,
        };
        let measured = self.zernike_pupil_diameter_mm.unwrap_or(self.pupil_diameter_mm);
        let z = ZernikeCoefficients::new(measured, self.zernike_um.clone()).map_err(|e| bad(e.to_string()))?;
        let mut z = z.rescaled(self.pupil_diameter_mm).map_err(|e| bad(e.to_string()))?;
        if z.coefficients_um.len() < 28 {
            z.coefficients_um.resize(28, 0.0);
        }
        if let Some(p) = &self.prescription {
            // The refractive error's wavefront (Thibos power vectors) adds to the measured one.
            let lens = ZernikeCoefficients::from_prescription(p, self.pupil_diameter_mm);
            for j in 3..=5 {
                z.coefficients_um[j] += lens.get(j);
            }
        }
        Ok(z.with_order_range_zeroed(0..=1))
    }

    /// The wavelength the aberrations are referenced to, nm.
    pub fn reference_wavelength(&self) -> f64 {
        self.reference_wavelength_nm
            .unwrap_or(crate::physics::chromatic::DEFAULT_REFERENCE_WAVELENGTH_NM)
    }

    /// The wavefront at the viewing pupil for light of `wavelength_nm`: [`Self::effective_wavefront`] plus the
    /// eye's chromatic defocus relative to the reference wavelength (Thibos et al. 1992).
    pub fn wavefront_at(&self, wavelength_nm: f64) -> Result<ZernikeCoefficients, ProfileError> {
        Ok(crate::physics::chromatic::at_wavelength(
            &self.effective_wavefront()?,
            wavelength_nm,
            self.reference_wavelength(),
        ))
    }

    /// The person's cone fundamentals.
    pub fn cone_fundamentals(&self) -> ConeFundamentals {
        self.spectral.cone_fundamentals()
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_wavefront_in_the_blue_band_gains_the_chromatic_defocus() {
        // A perfect eye referenced at 555 nm: at 450 nm it is −0.827 D myopic (Thibos 1992), which at a 6 mm
        // pupil is c₂⁰ = 0.827·9/(4√3) = 1.074 µm; at the reference wavelength nothing is added.
        let p = VisionProfile::perfect();
        let blue = p.wavefront_at(450.0).unwrap();
        assert!((blue.coefficients_um[4] - 0.827091 * 9.0 / (4.0 * 3f64.sqrt())).abs() < 1e-5);
        assert_eq!(p.wavefront_at(555.0).unwrap(), p.effective_wavefront().unwrap());
        let bad = VisionProfile {
            reference_wavelength_nm: Some(5.0),
            ..VisionProfile::perfect()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("reference_wavelength_nm"));
    }

    use super::*;

    #[test]
    fn perfect_profile_round_trips_through_json() {
        let p = VisionProfile::perfect();
        let text = serde_json::to_string(&p).unwrap();
        let q = VisionProfile::from_json(&text).unwrap();
        assert_eq!(p, q);
    }

    #[test]
    fn a_60_mm_pupil_is_refused_naming_the_field() {
        let mut p = VisionProfile::perfect();
        p.pupil_diameter_mm = 60.0;
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("pupil_diameter_mm"), "{e}");
    }

    #[test]
    fn bad_coefficients_and_unknown_fields_are_refused() {
        let mut p = VisionProfile::perfect();
        p.zernike_um[7] = 300.0;
        assert!(p.validate().unwrap_err().to_string().contains("zernike_um[7]"));
        let e = VisionProfile::from_json(r#"{"pupil_diameter_mm": 6, "zernike_um": [], "colour": 1}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("colour"), "{e}");
    }

    #[test]
    fn prescription_adds_defocus_to_the_effective_wavefront() {
        let mut p = VisionProfile::perfect();
        p.prescription = Some(Prescription {
            sphere_d: -2.0,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        });
        let w = p.effective_wavefront().unwrap();
        // −2.00 D at 6 mm: C(2,0) = −M·r²/(4√3) = 2·9/(4√3) = 2.598 µm.
        assert!((w.get(4) - 2.598).abs() < 1e-3, "{}", w.get(4));
        // Refocusing adds to the sphere: the perfect eye refocused by −2 D meets the same wavefront, and the
        // prescribed eye refocused by +2 D none.
        let refocused = VisionProfile::perfect().refocused(-2.0).effective_wavefront().unwrap();
        assert!((refocused.get(4) - 2.598).abs() < 1e-3, "{}", refocused.get(4));
        assert!(p.refocused(2.0).effective_wavefront().unwrap().get(4).abs() < 1e-9);
    }

    #[test]
    fn a_changed_pupil_rescales_the_measured_wavefront_and_never_grows_past_it() {
        // Pure defocus measured over 6 mm seen through 5 mm: the same dioptric power, so c(2,0) scales by (5/6)²
        // (ISO 24157 Annex B, the closed form for defocus alone).
        let mut p = VisionProfile::perfect();
        p.zernike_um = vec![0.0, 0.0, 0.0, 0.0, 0.9];
        let narrower = p.with_pupil_changed(-1.0);
        assert_eq!(narrower.pupil_diameter_mm, 5.0);
        let c4 = narrower.effective_wavefront().unwrap().get(4);
        assert!((c4 - 0.9 * (5.0f64 / 6.0).powi(2)).abs() < 1e-12, "{c4}");
        // Back out to the measured pupil, the wavefront is the measured one; beyond it, the eye is not known.
        assert!((narrower.with_pupil_changed(0.5).pupil_diameter_mm - 5.5).abs() < 1e-12);
        assert_eq!(narrower.with_pupil_changed(3.0).pupil_diameter_mm, 6.0);
        assert!((narrower.with_pupil_changed(1.0).effective_wavefront().unwrap().get(4) - 0.9).abs() < 1e-12);
        assert_eq!(p.with_pupil_changed(-9.0).pupil_diameter_mm, 2.0);
    }
}
