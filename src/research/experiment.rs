//! `eyekey experiment`: the paper's §7.3 synthesized evaluation, a design-space sweep, and views for the
//! legibility calibration. Each writes pictures and a Markdown table into an output directory.

use eyekey_core::physics::transport::TransportCache;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use image::RgbImage;
use serde::Serialize;

use eyekey_core::encoding::pipeline::{encode, Ablation, DecoyKind, EncodeOptions, JobSpec, Method, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{evaluate, EvaluationOptions, Reference};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::spectral::{ObserverParameters, SpectralSensitivity};
use eyekey_core::physics::transport::{EyePosition, TransportOptions};

/// The three observers of the paper's §7.3: they differ in four higher-order Zernike coefficients (coma and
/// trefoil, j = 6..=9; low orders are assumed corrected by spectacles) and in their cones.
pub fn paper_observers() -> Vec<(String, VisionProfile)> {
    let person = |ho: [f64; 4], spectral: ObserverParameters| {
        let mut p = VisionProfile::perfect();
        p.zernike_um[6..10].copy_from_slice(&ho);
        p.spectral = SpectralSensitivity::Parameters(spectral);
        p
    };
    vec![
        (
            "(i) target".into(),
            person(
                [0.10, -0.15, 0.12, 0.05],
                ObserverParameters {
                    age_years: 28.0,
                    shift_l_nm: 1.5,
                    od_macula_pct: 30.0,
                    ..Default::default()
                },
            ),
        ),
        // The representative: the standard observer's cones and a typical (population-mean-sized) aberration.
        (
            "(ii) representative".into(),
            person([-0.02, -0.03, 0.0, 0.0], ObserverParameters::default()),
        ),
        (
            "(iii) other".into(),
            person(
                [-0.12, 0.18, -0.05, 0.10],
                ObserverParameters {
                    age_years: 55.0,
                    shift_m_nm: -1.5,
                    od_lens_pct: 20.0,
                    ..Default::default()
                },
            ),
        ),
    ]
}

/// A PIN slip: the test document of the experiments.
pub fn pin_slip(width: u32, height: u32) -> RgbImage {
    eyekey_core::imaging::glyphs::render_text(&["PIN", "4821"], width, height, (width / 28).max(1))
}

#[derive(Serialize)]
struct Row {
    figure: String,
    variant: String,
    observer: String,
    legibility: f64,
    ncc: f64,
    psnr_db: f64,
    ssim: f64,
    readable: bool,
}

fn save(img: &RgbImage, dir: &Path, name: &str) -> Result<()> {
    eyekey_core::imaging::save_rgb_png(img, &dir.join(name))?;
    Ok(())
}

/// A strip of labelled tiles.
fn strip(tiles: &[(String, RgbImage)]) -> RgbImage {
    let tile = 150u32;
    let mut sheet = RgbImage::from_pixel(
        tiles.len() as u32 * (tile + 6) + 6,
        tile + 30,
        image::Rgb([255, 255, 255]),
    );
    for (k, (label, pic)) in tiles.iter().enumerate() {
        let x0 = 6 + k as u32 * (tile + 6);
        let scaled = image::imageops::resize(pic, tile, tile, image::imageops::FilterType::Nearest);
        image::imageops::replace(&mut sheet, &scaled, x0 as i64, 6);
        let text = eyekey_core::imaging::glyphs::render_text(&[label], tile, 22, 2);
        image::imageops::replace(&mut sheet, &text, x0 as i64, (tile + 8) as i64);
    }
    sheet
}

/// Reproduces the paper's §7.3 (Figs. 13–15) on the `paper` preset; writes pictures and `results.md`.
pub fn paper(out: &Path, max_iterations: u32, population: u32) -> Result<String> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let cache = TransportCache::default();
    let display = DisplayGeometry::paper();
    let observers = paper_observers();
    let g = (display.holes_x * 2, display.holes_y * 2);
    let document = pin_slip(g.0, g.1);
    let decoy = eyekey_core::imaging::glyphs::render_text(&["XXXX", "0000"], g.0, g.1, (g.0 / 28).max(1));
    save(&document, out, "document.png")?;
    let topts = TransportOptions {
        sub_rays: 16,
        seed: 977,
        ..Default::default()
    };
    let viewers: Vec<Observer> = observers
        .iter()
        .map(|(_, p)| Observer::new(&display, p, EyePosition::default(), &topts, &cache))
        .collect::<Result<_, _>>()?;
    let grid = viewers[0].transport.grid;
    let reference = Reference::new(
        &document,
        grid.width,
        grid.height,
        OBJECTIVE_LEVEL,
        eyekey_core::evaluation::DEFAULT_THRESHOLD,
    );
    let mut rows = Vec::new();
    let mut md = String::new();
    let cancel = AtomicBool::new(false);
    // A plain display shows the document at the display's full white, not at the encoders' objective level.
    let plain_reference = Reference::new(
        &document,
        grid.width,
        grid.height,
        1.0,
        eyekey_core::evaluation::DEFAULT_THRESHOLD,
    );
    let score_all = |figure: &str, variant: &str, l: &[f32], rows: &mut Vec<Row>| -> Vec<(String, RgbImage)> {
        let mut tiles = Vec::new();
        let reference = if figure == "13" { &plain_reference } else { &reference };
        for ((name, _), v) in observers.iter().zip(&viewers) {
            let (s, pic) = reference.score_observer(name, v, l);
            tiles.push((
                format!("{} {:.2}", name.split(' ').next().unwrap_or(""), s.legibility),
                pic,
            ));
            rows.push(Row {
                figure: figure.into(),
                variant: variant.into(),
                observer: name.clone(),
                legibility: s.legibility,
                ncc: s.ncc,
                psnr_db: s.psnr_db,
                ssim: s.ssim,
                readable: s.readable,
            });
        }
        tiles
    };
    // Fig. 13: the document on a plain 2D display.
    let plain = plain_light_field_for_image(&display, &document);
    let tiles = score_all("13", "plain 2D display", &plain, &mut rows);
    save(&strip(&tiles), out, "fig13_plain.png")?;
    let mut timings = Vec::new();
    for (fig, method) in [("14", Method::Multiplex), ("15", Method::Diffmax)] {
        for (variant, ablation) in [
            ("proposed", None),
            ("optical only", Some(Ablation::Optical)),
            ("spectral only", Some(Ablation::Spectral)),
        ] {
            let spec = JobSpec {
                display: display.clone(),
                target: observers[0].1.clone(),
                target_label: "paper (i)".into(),
                observers: if method == Method::Multiplex {
                    vec![observers[1].1.clone()]
                } else {
                    vec![]
                },
                document: document.clone(),
                decoy: Some(decoy.clone()),
                options: EncodeOptions {
                    method,
                    ablation,
                    population_decoys: 0,
                    decoy: DecoyKind::Image,
                    max_iterations,
                    sub_rays: 16,
                    ..Default::default()
                },
            };
            let t = Instant::now();
            let enc = encode(&spec, &cache, &|_| {}, &cancel)?;
            timings.push(format!(
                "Fig. {fig} {variant}: {:.1} s, {} iterations",
                t.elapsed().as_secs_f64(),
                enc.solver.iterations
            ));
            let tiles = score_all(fig, variant, &enc.light_field, &mut rows);
            let file = format!("fig{fig}_{}.png", variant.replace(' ', "_"));
            save(&strip(&tiles), out, &file)?;
        }
    }
    // The population's view of the proposed multiplex encoding (not in the paper, which had three observers).
    writeln!(
        md,
        "| figure | encoding | observer | legibility | NCC | PSNR (dB) | SSIM | readable |"
    )?;
    writeln!(md, "| --- | --- | --- | --- | --- | --- | --- | --- |")?;
    for r in &rows {
        writeln!(
            md,
            "| {} | {} | {} | {:.2} | {:.2} | {:.1} | {:.2} | {} |",
            r.figure,
            r.variant,
            r.observer,
            r.legibility,
            r.ncc,
            r.psnr_db,
            r.ssim,
            if r.readable { "yes" } else { "no" }
        )?;
    }
    if population > 0 {
        let spec_opts = EncodeOptions {
            method: Method::Multiplex,
            population_decoys: 0,
            max_iterations,
            ..Default::default()
        };
        let spec = JobSpec {
            display: display.clone(),
            target: observers[0].1.clone(),
            target_label: "paper (i)".into(),
            observers: vec![observers[1].1.clone()],
            document: document.clone(),
            decoy: Some(decoy.clone()),
            options: EncodeOptions {
                decoy: DecoyKind::Image,
                ..spec_opts
            },
        };
        let enc = encode(&spec, &cache, &|_| {}, &cancel)?;
        let ev = evaluate(
            &display,
            &enc.light_field,
            &document,
            OBJECTIVE_LEVEL,
            &observers[0].1,
            &[],
            &EvaluationOptions {
                population,
                key_directions: 0,
                head_offsets_mm: vec![],
                ..Default::default()
            },
            &cache,
            &|_| {},
            &cancel,
        )?;
        if let Some(p) = &ev.report.population {
            writeln!(
                md,
                "\nPopulation check of the proposed multiplex encoding (Fig. 14 (c)–(e)): {}/{} sampled people can read \
                 (median legibility {:.2}, 95th percentile {:.2}, max {:.2}); camera attacker's best {:.2}.",
                p.readable_count,
                p.count,
                p.median_legibility,
                p.p95_legibility,
                p.max_legibility,
                ev.report.camera.as_ref().map_or(0.0, |c| c.best.legibility)
            )?;
        }
        eyekey_core::encoding::pipeline::write_evaluation(&ev, &out.join("fig14_population"))?;
    }
    writeln!(md, "\nTimings: {}.", timings.join("; "))?;
    std::fs::write(out.join("results.md"), &md)?;
    std::fs::write(out.join("results.json"), serde_json::to_string_pretty(&rows)?)?;
    Ok(md)
}

/// One point of the design-space sweep.
#[derive(Clone, Debug, Serialize)]
pub struct SweepPoint {
    /// What was varied.
    pub label: String,
    /// The display.
    pub display: DisplayGeometry,
    /// Viewing pupil of the target, mm.
    pub pupil_mm: f64,
    /// Decoy observers K − 1.
    pub decoys: u32,
    /// Decoy strategy.
    pub decoy: DecoyKind,
    /// Decoy weight.
    pub decoy_weight: f64,
    /// Target legibility.
    pub target_legibility: f64,
    /// Fraction of the sampled population that can read.
    pub readable_fraction: f64,
    /// 95th-percentile legibility of the population.
    pub p95_legibility: f64,
    /// Camera attacker's best legibility.
    pub camera_best: f64,
    /// Seconds for encode + evaluation.
    pub seconds: f64,
}

fn sweep_display(views: u32, pitch_mm: f64, distance_mm: f64, holes: u32, bands: usize) -> DisplayGeometry {
    // Views spaced so that `views` of them span 6.6 mm at the pupil: p_s·d/g = 6.6/views.
    let p_s = pitch_mm / views as f64;
    let spacing = 6.6 / views as f64;
    let projectors = eyekey_core::physics::spectral::paper_projectors();
    let projectors = match bands {
        3 => vec![projectors[0].clone(), projectors[1].clone(), projectors[3].clone()],
        _ => projectors,
    };
    DisplayGeometry {
        holes_x: holes,
        holes_y: holes,
        hole_pitch_mm: pitch_mm,
        hole_diameter_mm: p_s,
        views_u: views,
        views_v: views,
        screen_pixel_pitch_mm: p_s,
        gap_mm: p_s * distance_mm / spacing,
        viewing_distance_mm: distance_mm,
        projectors,
        l_max: 1.0,
    }
}

/// Maps the design space to (target legibility, fraction of a sampled population that can read).
pub fn sweep(out: &Path, population: u32, max_iterations: u32) -> Result<(String, Vec<SweepPoint>)> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let cache = TransportCache::default();
    let target = {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(4242);
        eyekey_core::physics::population::sample_person(
            &mut rng,
            eyekey_core::physics::population::SamplingScope {
                pupil_spread: false,
                ..Default::default()
            },
        )
    };
    let base = |label: &str| {
        (
            label.to_string(),
            sweep_display(7, 0.3, 500.0, 32, 4),
            6.0,
            6u32,
            DecoyKind::Noise,
            0.3,
            0u32,
        )
    };
    let mut configs = vec![base(
        "baseline: 7×7 views, 0.3 mm, 500 mm, 4 bands, 6 noise decoys w=0.3",
    )];
    for v in [3u32, 5, 9] {
        let mut c = base(&format!("views {v}×{v}"));
        c.1 = sweep_display(v, 0.3, 500.0, 32, 4);
        configs.push(c);
    }
    for p in [4.0, 5.0] {
        let mut c = base(&format!("pupil {p} mm"));
        c.2 = p;
        configs.push(c);
    }
    for d in [350.0, 700.0] {
        let mut c = base(&format!("viewing distance {d} mm"));
        c.1 = sweep_display(7, 0.3, d, 32, 4);
        configs.push(c);
    }
    for pitch in [0.2, 0.45] {
        let mut c = base(&format!("hole pitch {pitch} mm"));
        c.1 = sweep_display(7, pitch, 500.0, 32, 4);
        configs.push(c);
    }
    {
        let mut c = base("3 bands");
        c.1 = sweep_display(7, 0.3, 500.0, 32, 3);
        configs.push(c);
    }
    for (k, w) in [(0u32, 0.3), (2, 0.3), (12, 0.3), (12, 0.15), (6, 0.6), (24, 0.1)] {
        let mut c = base(&format!("K−1 = {k} decoys, weight {w}"));
        c.3 = k;
        c.5 = w;
        configs.push(c);
    }
    {
        let mut c = base("grey decoys");
        c.4 = DecoyKind::Grey;
        configs.push(c);
    }
    {
        let mut c = base("9×9 views, 12 decoys w=0.2");
        c.1 = sweep_display(9, 0.3, 500.0, 32, 4);
        c.3 = 12;
        c.5 = 0.2;
        configs.push(c);
    }
    {
        let mut c = base("9×9 views, 12 decoys w=0.2, 2 adaptive rounds");
        c.1 = sweep_display(9, 0.3, 500.0, 32, 4);
        c.3 = 12;
        c.5 = 0.2;
        c.6 = 2;
        configs.push(c);
    }
    {
        let mut c = base("7×7 views, 6 decoys w=0.3, 2 adaptive rounds");
        c.6 = 2;
        configs.push(c);
    }
    let cancel = AtomicBool::new(false);
    let mut points = Vec::new();
    for (label, display, pupil, decoys, decoy, weight, adaptive_rounds) in configs {
        let t = Instant::now();
        let g = (display.holes_x * 4, display.holes_y * 4);
        let document = pin_slip(g.0, g.1);
        let mut tgt = target.clone();
        if pupil < tgt.pupil_diameter_mm {
            let z =
                eyekey_core::physics::zernike::ZernikeCoefficients::new(tgt.pupil_diameter_mm, tgt.zernike_um.clone())?;
            tgt.zernike_um = z.rescaled(pupil)?.coefficients_um;
            tgt.pupil_diameter_mm = pupil;
        }
        let spec = JobSpec {
            display: display.clone(),
            target: tgt.clone(),
            target_label: "sweep".into(),
            observers: vec![],
            document: document.clone(),
            decoy: None,
            options: EncodeOptions {
                population_decoys: decoys,
                decoy,
                decoy_weight: weight,
                max_iterations,
                sub_rays: 12,
                seed: 5,
                adaptive_rounds,
                adaptive_candidates: 32,
                adaptive_per_round: 6,
                ..Default::default()
            },
        };
        let enc = encode(&spec, &cache, &|_| {}, &cancel)?;
        let ev = evaluate(
            &display,
            &enc.light_field,
            &document,
            OBJECTIVE_LEVEL,
            &tgt,
            &[],
            &EvaluationOptions {
                population,
                sub_rays: 12,
                key_directions: 0,
                head_offsets_mm: vec![],
                camera_focus_d: vec![-1.0, 0.0, 1.0],
                camera_apertures_mm: vec![2.0, 6.0],
                ..Default::default()
            },
            &cache,
            &|_| {},
            &cancel,
        )?;
        let p = ev.report.population.as_ref().context("population evaluated")?;
        let point = SweepPoint {
            label,
            display,
            pupil_mm: pupil,
            decoys,
            decoy,
            decoy_weight: weight,
            target_legibility: ev.report.target.legibility,
            readable_fraction: p.readable_fraction,
            p95_legibility: p.p95_legibility,
            camera_best: ev.report.camera.as_ref().map_or(0.0, |c| c.best.legibility),
            seconds: t.elapsed().as_secs_f64(),
        };
        eprintln!(
            "{:<60} target {:.2}  readable {:>5.1} %  p95 {:.2}  camera {:.2}  ({:.1} s)",
            point.label,
            point.target_legibility,
            100.0 * point.readable_fraction,
            point.p95_legibility,
            point.camera_best,
            point.seconds
        );
        points.push(point);
    }
    let mut md = String::new();
    writeln!(
        md,
        "| configuration | target legibility | population readable | population p95 | camera best | seconds |"
    )?;
    writeln!(md, "| --- | --- | --- | --- | --- | --- |")?;
    for p in &points {
        writeln!(
            md,
            "| {} | {:.2} | {:.1} % | {:.2} | {:.2} | {:.1} |",
            p.label,
            p.target_legibility,
            100.0 * p.readable_fraction,
            p.p95_legibility,
            p.camera_best,
            p.seconds
        )?;
    }
    // The frontier: points not dominated in (high target legibility, low readable fraction).
    let frontier: Vec<&SweepPoint> = points
        .iter()
        .filter(|a| {
            !points.iter().any(|b| {
                b.target_legibility >= a.target_legibility
                    && b.readable_fraction <= a.readable_fraction
                    && (b.target_legibility > a.target_legibility || b.readable_fraction < a.readable_fraction)
            })
        })
        .collect();
    writeln!(md, "\nPareto frontier (target legibility ↑, population readable ↓):\n")?;
    for p in &frontier {
        writeln!(
            md,
            "- {}: target {:.2}, readable {:.1} %",
            p.label,
            p.target_legibility,
            100.0 * p.readable_fraction
        )?;
    }
    // The `secure` preset is chosen from the frontier: the fewest readers among points where the target reads
    // with legibility ≥ 0.85.
    if let Some(best) = frontier
        .iter()
        .filter(|p| p.target_legibility >= 0.85)
        .min_by(|a, b| a.readable_fraction.total_cmp(&b.readable_fraction))
    {
        writeln!(
            md,
            "\nChosen for the `secure` preset (fewest readers with target legibility ≥ 0.85): **{}** (target {:.2}, readable {:.1} %).",
            best.label,
            best.target_legibility,
            100.0 * best.readable_fraction
        )?;
    }
    std::fs::write(out.join("sweep.md"), &md)?;
    std::fs::write(out.join("sweep.json"), serde_json::to_string_pretty(&points)?)?;
    Ok((md, points))
}

/// Encodes a PIN slip for a sampled target on the `secure` preset and evaluates it against `population`
/// sampled people, a camera attacker, key sensitivity and head movement.
pub fn secure(out: &Path, population: u32) -> Result<String> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let cache = TransportCache::default();
    let display = DisplayGeometry::secure();
    let target = {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(4242);
        eyekey_core::physics::population::sample_person(
            &mut rng,
            eyekey_core::physics::population::SamplingScope {
                pupil_spread: false,
                ..Default::default()
            },
        )
    };
    std::fs::write(
        out.join("target_profile_example.json"),
        serde_json::to_string_pretty(&target)?,
    )?;
    let g = (display.holes_x * 4, display.holes_y * 4);
    let document = pin_slip(g.0, g.1);
    let options = secure_encode_options();
    let spec = JobSpec {
        display: display.clone(),
        target: target.clone(),
        target_label: "secure experiment".into(),
        observers: vec![],
        document: document.clone(),
        decoy: None,
        options: options.clone(),
    };
    let cancel = AtomicBool::new(false);
    let t = Instant::now();
    let enc = encode(&spec, &cache, &|_| {}, &cancel)?;
    let t_encode = t.elapsed().as_secs_f64();
    let bundle = out.join("bundle");
    if bundle.exists() {
        std::fs::remove_dir_all(&bundle)?;
    }
    eyekey_core::encoding::pipeline::write_outputs(&spec, &enc, &bundle, false, &cache, &|_| {}, &cancel)?;
    let t = Instant::now();
    let ev = evaluate(
        &display,
        &enc.light_field,
        &document,
        OBJECTIVE_LEVEL,
        &target,
        &[],
        &EvaluationOptions {
            population,
            key_directions: 4,
            ..Default::default()
        },
        &cache,
        &|_| {},
        &cancel,
    )?;
    let t_eval = t.elapsed().as_secs_f64();
    eyekey_core::encoding::pipeline::write_evaluation(&ev, &out.join("evaluation"))?;
    let r = &ev.report;
    let mut md = String::new();
    writeln!(md, "| quantity | value |\n| --- | --- |")?;
    writeln!(
        md,
        "| display | `secure` preset: {}×{} holes at {} mm, {}×{} views, {} bands |",
        display.holes_x,
        display.holes_y,
        display.hole_pitch_mm,
        display.views_u,
        display.views_v,
        display.n_bands()
    )?;
    writeln!(
        md,
        "| encoder | multiplex, {} population decoys (noise masks), decoy weight {}, {} adaptive rounds of {} candidates (decoys added: {}), camera decoys: {} |",
        options.population_decoys,
        options.decoy_weight,
        options.adaptive_rounds,
        options.adaptive_candidates,
        serde_json::json!(enc.solver.adaptive_decoys_added),
        options.camera_decoys
    )?;
    writeln!(
        md,
        "| target legibility / PSNR / SSIM | {:.2} / {:.1} dB / {:.2} |",
        r.target.legibility, r.target.psnr_db, r.target.ssim
    )?;
    if let Some(p) = &r.population {
        writeln!(
            md,
            "| sampled people who can read | {} of {} ({:.1} %) |",
            p.readable_count,
            p.count,
            100.0 * p.readable_fraction
        )?;
        writeln!(
            md,
            "| population legibility median / 95th pct / max | {:.2} / {:.2} / {:.2} |",
            p.median_legibility, p.p95_legibility, p.max_legibility
        )?;
        let levels: Vec<String> = p
            .fraction_at_or_above
            .iter()
            .map(|(t, f)| format!("≥ {t:.2}: {:.1} %", 100.0 * f))
            .collect();
        writeln!(
            md,
            "| population at or above legibility levels | {} |",
            levels.join(", ")
        )?;
    }
    if let Some(c) = &r.camera {
        writeln!(
            md,
            "| camera attacker's best | {:.2} ({}) |",
            c.best.legibility, c.best.label
        )?;
    }
    if let Some(k) = &r.key_sensitivity {
        writeln!(
            md,
            "| optical key radius / bits | {:.3} µm / {:.1} bits |",
            k.optical_radius_um, k.optical_bits
        )?;
        writeln!(
            md,
            "| spectral key radius / bits | {:.2} SD / {:.1} bits |",
            k.spectral_radius_sd, k.spectral_bits
        )?;
        writeln!(
            md,
            "| empirical bound from the population sample | {:.1} bits |",
            k.empirical_bits
        )?;
    }
    if let Some(h) = &r.head_movement {
        writeln!(
            md,
            "| target still reads within | {:.1} mm of the design eye position |",
            h.readable_radius_mm
        )?;
    }
    writeln!(md, "| encode / evaluation time | {t_encode:.1} s / {t_eval:.1} s |")?;
    std::fs::write(out.join("results.md"), &md)?;
    Ok(md)
}

/// The encoder options paired with the `secure` preset (chosen from the sweep's frontier).
pub fn secure_encode_options() -> EncodeOptions {
    EncodeOptions {
        population_decoys: 12,
        decoy_weight: 0.2,
        max_iterations: 300,
        adaptive_rounds: 2,
        adaptive_candidates: 32,
        adaptive_per_round: 6,
        camera_decoys: true,
        ..Default::default()
    }
}
