//! `eyekey experiment wave`: frames encoded under each forward model, seen under both.
//!
//! Encodes a PIN slip for a sampled target twice, inverting the geometric model and the wave model, then scores
//! what the target and a bystander at the target's seat see of each, and what the target sees of the plain
//! document, under the geometric and the wave model (docs/design.md §2.7). The wave figures are what a real rig
//! would show.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;

use anyhow::Result;

use eyekey_core::encoding::pipeline::{encode, EncodeOptions, JobSpec, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{Reference, DEFAULT_THRESHOLD};

use eyekey_core::physics::display::{Aperture, DisplayGeometry};
use eyekey_core::physics::fourier::{view_lms, FourierSampling};
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer, Optics};
use eyekey_core::physics::population::sample_population;
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::resolvability::Resolvability;
use eyekey_core::physics::transport::{EyePosition, TransportCache, TransportOptions};

use super::experiment::{pin_slip, sampled_target};

/// One viewer's legibility of one light field under both models, and the pictures.
struct Scored {
    geometric: f64,
    wave: f64,
    /// The same view by the independent Fourier-optics model, when asked for.
    fourier: Option<f64>,
}

/// Saves a retinal picture enlarged to at least 192 pixels across (nearest neighbour), so it can be looked at.
fn save_enlarged(pic: &image::RgbImage, path: &Path) -> Result<()> {
    let k = (192 / pic.width().max(1)).max(1);
    let big = image::imageops::resize(
        pic,
        pic.width() * k,
        pic.height() * k,
        image::imageops::FilterType::Nearest,
    );
    Ok(eyekey_core::imaging::save_rgb_png(&big, path)?)
}

/// Scores `l` for `person` under both models (and, with `fourier`, the Fourier-optics one); saves the pictures
/// as `<name>_geometric.png`, `_wave.png` and `_fourier.png`.
#[allow(clippy::too_many_arguments)]
fn score(
    display: &DisplayGeometry,
    person: &VisionProfile,
    l: &[f32],
    document: &image::RgbImage,
    out: &Path,
    name: &str,
    cache: &TransportCache,
    fourier: bool,
) -> Result<Scored> {
    // The evaluation's own jitter seed, never the encoder's.
    let topts = TransportOptions {
        sub_rays: 16,
        seed: 0xE7A1,
        ..Default::default()
    };
    let eye = EyePosition::default();
    let g = Observer::new(display, person, eye, &topts, Optics::Geometric, cache)?;
    let grid = g.grid();
    let reference = Reference::new(document, grid.width, grid.height, OBJECTIVE_LEVEL, DEFAULT_THRESHOLD);
    let (gs, gpic) = reference.score_observer(name, &g, l);
    save_enlarged(&gpic, &out.join(format!("{name}_geometric.png")))?;
    let w = Observer::new(display, person, eye, &topts, Optics::Wave, cache)?;
    let view = w.view(l);
    let ws = reference.score_lms(name, &view, w.white);
    save_enlarged(&w.picture(&view), &out.join(format!("{name}_wave.png")))?;
    let fourier = if fourier {
        let sampling = FourierSampling {
            n: if display.aperture == Aperture::Lenslet {
                256
            } else {
                512
            },
            extent_mm: 6.0,
            source_points: 2,
        };
        let view = view_lms(display, person, l, sampling, 1)?;
        save_enlarged(&w.picture(&view), &out.join(format!("{name}_fourier.png")))?;
        Some(reference.score_lms(name, &view, w.white).legibility)
    } else {
        None
    };
    Ok(Scored {
        geometric: gs.legibility,
        wave: ws.legibility,
        fourier,
    })
}

/// Runs the check on `display` and returns the Markdown table it also writes to `out/results.md`.
///
/// With `fourier`, the target's views are also computed by the independent Fourier-optics model
/// ([`eyekey_core::physics::fourier::view_lms`]), minutes per view.
pub fn run(out: &Path, display: &DisplayGeometry, label: &str, fourier: bool) -> Result<String> {
    std::fs::create_dir_all(out)?;
    let cache = TransportCache::default();
    let target = sampled_target();
    let bystander = sample_population(1, 12, Default::default()).remove(0);
    let g = (display.holes_x * 4, display.holes_y * 4);
    let document = pin_slip(g.0, g.1);
    let spec = JobSpec {
        display: display.clone(),
        target: target.clone(),
        target_label: "wave check".into(),
        observers: Vec::new(),
        document: document.clone(),
        decoy: None,
        // Encoded as eyekey did before it modelled diffraction, to measure what that model promised.
        options: EncodeOptions {
            optics: Optics::Geometric,
            population_decoys: 6,
            near_pupil_decoys: 0,
            decoy_weight: Some(1.0),
            leak_weight: 0.0,
            ensure_target_reads: false,
            seed: Some(crate::research::EXPERIMENT_SEED),
            ..Default::default()
        },
    };
    let geometric = encode(&spec, &cache, &|_| {}, &AtomicBool::new(false))?;
    let wave_spec = JobSpec {
        options: EncodeOptions {
            optics: Optics::Wave,
            ..spec.options.clone()
        },
        ..spec.clone()
    };
    let wave = encode(&wave_spec, &cache, &|_| {}, &AtomicBool::new(false))?;
    let plain = plain_light_field_for_image(display, &document);
    let mut rows = vec![(
        "target, plain document".to_string(),
        score(
            display,
            &target,
            &plain,
            &document,
            out,
            "target_plain",
            &cache,
            fourier,
        )?,
    )];
    for (model, encoded) in [("geometric", &geometric), ("wave", &wave)] {
        let l = &encoded.light_field;
        rows.push((
            format!("target, frames encoded under {model} optics"),
            score(
                display,
                &target,
                l,
                &document,
                out,
                &format!("target_{model}_frames"),
                &cache,
                fourier,
            )?,
        ));
        rows.push((
            format!("bystander at the target's seat, frames encoded under {model} optics"),
            score(
                display,
                &bystander,
                l,
                &document,
                out,
                &format!("bystander_{model}_frames"),
                &cache,
                false,
            )?,
        ));
    }
    let r = Resolvability::of(display);
    let m: Vec<String> = r.bands.iter().map(|b| format!("{:.2}", b.resolvability)).collect();
    let mut md = format!(
        "Preset `{label}` ({} holes of {:.3} mm, {}×{} views, {} mm), resolvability M per band: {}. Frames encoded \
         under each model (multiplex, {} population decoys, {}/{} iterations); legibility threshold \
         {DEFAULT_THRESHOLD}.\n\n| viewer | legibility, geometric | legibility, wave | legibility, wave (Fourier optics) |\n| --- | --- | --- | --- |\n",
        display.aperture.as_str(),
        display.hole_diameter_mm,
        display.views_u,
        display.views_v,
        display.viewing_distance_mm,
        m.join(", "),
        spec.options.population_decoys,
        geometric.solver.iterations,
        wave.solver.iterations
    );
    for (name, s) in &rows {
        let f = s.fourier.map_or("–".to_string(), |v| format!("{v:.2}"));
        writeln!(md, "| {name} | {:.2} | {:.2} | {f} |", s.geometric, s.wave)?;
    }
    md.push_str(&band_sampling(
        display,
        &[&target, &bystander],
        &wave.light_field,
        &document,
        &cache,
    )?);
    std::fs::write(out.join("results.md"), &md)?;
    Ok(md)
}

/// How many wavelengths a band needs (docs/design.md §2.7): the wave-encoded frames scored with each band
/// as 1, 3 (the default) and 5 wavelengths of equal power, and how far the views move (relative RMS against
/// 5 wavelengths).
fn band_sampling(
    display: &DisplayGeometry,
    people: &[&VisionProfile],
    l: &[f32],
    document: &image::RgbImage,
    cache: &TransportCache,
) -> Result<String> {
    let mut md = String::from(
        "\nWavelengths per band (the wave-encoded frames; the encoder used the default, 3):\n\n| wavelengths per band | target legibility | target view vs 5 wavelengths (relative RMS) | bystander legibility |\n| --- | --- | --- | --- |\n",
    );
    let eye = EyePosition::default();
    let views = |q: u32| -> Result<Vec<(f64, Vec<f32>)>> {
        let topts = TransportOptions {
            sub_rays: 16,
            seed: 0xE7A1,
            wavelengths_per_band: q,
            ..Default::default()
        };
        people
            .iter()
            .map(|p| {
                let o = Observer::new(display, p, eye, &topts, Optics::Wave, cache)?;
                let grid = o.grid();
                let reference = Reference::new(document, grid.width, grid.height, OBJECTIVE_LEVEL, DEFAULT_THRESHOLD);
                let view = o.view(l);
                Ok((reference.score_lms("band sampling", &view, o.white).legibility, view))
            })
            .collect()
    };
    let finest = views(5)?;
    for q in [1, 3, 5] {
        let v = views(q)?;
        let (t, b) = (&v[0], &v[1]);
        let num: f64 =
            t.1.iter()
                .zip(&finest[0].1)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum();
        let den: f64 = finest[0].1.iter().map(|b| (*b as f64).powi(2)).sum();
        writeln!(
            md,
            "| {q} | {:.2} | {:.3} | {:.2} |",
            t.0,
            (num / den.max(1e-30)).sqrt(),
            b.0
        )?;
    }
    Ok(md)
}
