//! `eyekey experiment encoders`: the encoder frontier. On the wave sweep's lenslet baseline (the display, target
//! and PIN slip of `eyekey experiment headbox`), each encoder variant is run and judged by the same held-out
//! people at the target's position (a seed the encoders never use), by the known-font attacker, and by a camera
//! at the target's position sweeping focus ±3 D at apertures of 2, 4 and 8 mm behind RGB and one-band filters.
//! One row per variant: the target's reading against the share of people and camera settings that read.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;

use super::bystanders::Baseline;
use super::table_header;
use eyekey_core::encoding::pipeline::EncodeOptions;
use eyekey_core::evaluation::{BystanderOptions, EvaluationOptions};
use eyekey_core::physics::observer::Optics;

/// One encoder variant: a label and its options over the baseline's.
struct Variant {
    label: String,
    options: EncodeOptions,
}

/// The variants measured, from the wave sweep's baseline (6 noise decoys at weight 0.3) outwards.
fn variants(max_iterations: u32) -> Vec<Variant> {
    let base = EncodeOptions {
        population_decoys: 6,
        near_pupil_decoys: 0,
        decoy_weight: Some(0.3),
        ..Baseline::options(max_iterations)
    };
    let v = |label: &str, options: EncodeOptions| Variant {
        label: label.into(),
        options,
    };
    let mut out = vec![
        v("6 noise decoys, weight 0.3 (the sweep's baseline)", base.clone()),
        v(
            "12 noise decoys, weight 0.2",
            EncodeOptions {
                population_decoys: 12,
                near_pupil_decoys: 0,
                decoy_weight: Some(0.2),
                ..base.clone()
            },
        ),
        v(
            "6 noise decoys + 2 adaptive rounds (24 candidates, up to 4 added each)",
            EncodeOptions {
                adaptive_rounds: 2,
                ..base.clone()
            },
        ),
        v(
            "6 noise decoys + camera decoys (±0.5 D, one band each)",
            EncodeOptions {
                camera_decoys: true,
                ..base.clone()
            },
        ),
    ];
    for (decoys, leak) in [(6, 1.0), (12, 0.5), (24, 0.3)] {
        out.push(v(
            &format!("{decoys} leak-only decoys, leak weight {leak}"),
            EncodeOptions {
                population_decoys: decoys,
                near_pupil_decoys: 0,
                decoy_weight: Some(0.0),
                leak_weight: leak,
                ..base.clone()
            },
        ));
    }
    out.push(v(
        "6 noise decoys, weight 0.3, + leak weight 1",
        EncodeOptions {
            leak_weight: 1.0,
            ..base.clone()
        },
    ));
    out.push(v(
        "6 noise decoys, weight 0.3, + leak weight 1 + camera decoys (±0.5 D, 6 mm)",
        EncodeOptions {
            leak_weight: 1.0,
            camera_decoys: true,
            ..base.clone()
        },
    ));
    out.push(v(
        "6 noise decoys, weight 0.3, + leak weight 1 + camera decoys (−1, 0, +1 D, 8 mm)",
        EncodeOptions {
            leak_weight: 1.0,
            camera_decoys: true,
            camera_decoy_focus_d: vec![-1.0, 0.0, 1.0],
            camera_decoy_aperture_mm: 8.0,
            ..base.clone()
        },
    ));
    out.push(v(
        "6 noise decoys, weight 0.3, + leak weight 1 + 2 adaptive rounds",
        EncodeOptions {
            leak_weight: 1.0,
            adaptive_rounds: 2,
            ..base.clone()
        },
    ));
    out.push(v(
        "12 noise decoys, weight 0.2, + leak weight 1",
        EncodeOptions {
            population_decoys: 12,
            near_pupil_decoys: 0,
            decoy_weight: Some(0.2),
            leak_weight: 1.0,
            ..base.clone()
        },
    ));
    out.push(v(
        "6 noise decoys, weight 0.3, + leak weight 3",
        EncodeOptions {
            leak_weight: 3.0,
            ..base.clone()
        },
    ));
    for (r, n) in [(3.0, 4), (4.0, 4), (5.0, 4), (6.0, 4), (6.4, 4), (5.0, 8)] {
        out.push(v(
            &format!("6 noise decoys, target stacked on a {r} mm ring ({n} positions)"),
            EncodeOptions {
                head_radius_mm: r,
                head_positions: n,
                ..base.clone()
            },
        ));
    }
    out.push(v(
        "6 noise decoys + leak weight 1, target stacked on a 5 mm ring",
        EncodeOptions {
            leak_weight: 1.0,
            head_radius_mm: 5.0,
            ..base.clone()
        },
    ));
    out
}

/// Runs every variant; `population` held-out people at the target's position judge each. Writes
/// `out/encoders.md` and `out/encoders.json`; returns the Markdown.
pub fn run(out: &Path, population: u32, max_iterations: u32, only: Option<&str>) -> Result<String> {
    std::fs::create_dir_all(out)?;
    let base = Baseline::new()?;
    let mut md = table_header(&[
        "encoder",
        "encode",
        "target: legibility, known font",
        "people at the target's position who read (95 % CI)",
        "… with at most one digit wrong",
        "population legibility p95",
        "camera settings at the target's position that read",
        "best camera",
    ]);
    let mut all = Vec::new();
    for variant in variants(max_iterations) {
        if only.is_some_and(|f| !variant.label.contains(f)) {
            continue;
        }
        let (l, t_encode) = base.encode_with(&variant.label, variant.options.clone())?;
        let cam = BystanderOptions::default();
        let (ev, t_eval) = base.evaluate(
            &l,
            &EvaluationOptions {
                optics: Optics::Wave,
                sub_rays: 12,
                camera_focus_d: cam.camera_focus_d.clone(),
                camera_apertures_mm: cam.camera_apertures_mm.clone(),
                ..EvaluationOptions::population_only(population, Some(base.text.clone()))
            },
            &|_| {},
        )?;
        let r = &ev.report;
        let p = r.population.as_ref().expect("a population was asked for");
        let (cam_read, cam_tried, cam_best) = r
            .camera
            .as_ref()
            .map(|c| {
                (
                    c.tried.iter().filter(|s| s.readable).count(),
                    c.tried.len(),
                    format!(
                        "{:.2}, {} ({})",
                        c.best.legibility,
                        super::known_font_cell(&c.best),
                        c.best.label
                    ),
                )
            })
            .unwrap_or((0, 0, "–".into()));
        writeln!(
            md,
            "| {} | {t_encode:.0} s | {:.2}, {}{} | {} of {} ({:.1}–{:.1} %) | {} | {:.2} | {cam_read} of {cam_tried} | {cam_best} |",
            variant.label,
            r.target.legibility,
            super::known_font_cell(&r.target),
            if r.target.readable { "" } else { " **not read**" },
            p.readable_count,
            p.count,
            100.0 * p.readable_ci95.0,
            100.0 * p.readable_ci95.1,
            p.known_font_all_but_one.unwrap_or(0),
            p.p95_legibility,
        )?;
        eprintln!("{} (evaluation {t_eval:.0} s)", md.lines().last().unwrap_or(""));
        all.push(serde_json::json!({
            "encoder": variant.label,
            "options": variant.options,
            "encode_seconds": t_encode,
            "evaluation_seconds": t_eval,
            "target": r.target,
            "population": p,
            "camera": r.camera,
        }));
    }
    std::fs::write(out.join("encoders.md"), &md)?;
    std::fs::write(out.join("encoders.json"), serde_json::to_string_pretty(&all)?)?;
    Ok(md)
}
