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

use super::table_header;
use eyekey_core::encoding::pipeline::{
    encode, Ablation, DecoyKind, EncodeOptions, Encoded, JobSpec, Method, OBJECTIVE_LEVEL,
};
use eyekey_core::evaluation::{evaluate, Evaluation, EvaluationOptions, PopulationSummary, Reference, Report};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer, Optics};
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
    pin_slip_of(width, height, "4821").0
}

/// The text of [`pin_slip`] `width` pixels wide, for the known-font attacker: the digits are secret.
pub fn pin_slip_text(width: u32) -> eyekey_core::evaluation::DocumentText {
    pin_slip_text_of(width, "4821")
}

/// A PIN slip showing `digits`, and its text hint.
pub fn pin_slip_of(width: u32, height: u32, digits: &str) -> (RgbImage, eyekey_core::evaluation::DocumentText) {
    let text = pin_slip_text_of(width, digits);
    let lines: Vec<&str> = text.lines.iter().map(String::as_str).collect();
    (
        eyekey_core::imaging::glyphs::render_text(&lines, width, height, text.scale),
        text,
    )
}

/// The text hint of a PIN slip `width` pixels wide showing `digits`.
fn pin_slip_text_of(width: u32, digits: &str) -> eyekey_core::evaluation::DocumentText {
    eyekey_core::evaluation::DocumentText {
        lines: vec!["PIN".into(), digits.into()],
        scale: (width / 28).max(1),
        alphabet: "0123456789".into(),
    }
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

/// What every step of the §7.3 reproduction shares: the display, the three observers, the documents and the
/// observers' operators.
struct PaperSetup {
    cache: TransportCache,
    /// The forward model of the encoders and of every viewer.
    optics: Optics,
    display: DisplayGeometry,
    observers: Vec<(String, VisionProfile)>,
    document: RgbImage,
    decoy: RgbImage,
    /// The observers' operators (16 sub-rays, jitter seed 977), in the order of `observers`.
    viewers: Vec<Observer>,
    /// The encoders' reference: the document at the objective level.
    reference: Reference,
    /// A plain display shows the document at the display's full white, not at the encoders' objective level.
    plain_reference: Reference,
}

impl PaperSetup {
    /// Builds the setup on the `paper` preset and saves `document.png` into `out`.
    fn new(out: &Path, optics: Optics) -> Result<Self> {
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
            .map(|(_, p)| Observer::new(&display, p, EyePosition::default(), &topts, optics, &cache))
            .collect::<Result<_, _>>()?;
        let grid = viewers[0].grid();
        let reference_at = |level: f64| {
            Reference::new(
                &document,
                grid.width,
                grid.height,
                level,
                eyekey_core::evaluation::DEFAULT_THRESHOLD,
            )
        };
        let (reference, plain_reference) = (reference_at(OBJECTIVE_LEVEL), reference_at(1.0));
        Ok(Self {
            cache,
            optics,
            display,
            observers,
            document,
            decoy,
            viewers,
            reference,
            plain_reference,
        })
    }

    /// Scores light field `l` for each of the three observers: appends their rows, returns their labelled tiles.
    fn score_all(&self, figure: &str, variant: &str, l: &[f32], rows: &mut Vec<Row>) -> Vec<(String, RgbImage)> {
        let mut tiles = Vec::new();
        let reference = if figure == "13" {
            &self.plain_reference
        } else {
            &self.reference
        };
        for ((name, _), v) in self.observers.iter().zip(&self.viewers) {
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
    }

    /// The job for observer (i) with the decoy image; multiplex also shows the decoy to observer (ii).
    fn spec(&self, options: EncodeOptions) -> JobSpec {
        JobSpec {
            display: self.display.clone(),
            target: self.observers[0].1.clone(),
            target_label: "paper (i)".into(),
            observers: if options.method == Method::Multiplex {
                vec![self.observers[1].1.clone()]
            } else {
                vec![]
            },
            document: self.document.clone(),
            decoy: Some(self.decoy.clone()),
            options,
        }
    }

    /// Encodes one figure's variant, scores it, saves its strip; returns the timing line.
    fn figure_variant(
        &self,
        out: &Path,
        (fig, method): (&str, Method),
        (variant, ablation): (&str, Option<Ablation>),
        max_iterations: u32,
        rows: &mut Vec<Row>,
    ) -> Result<String> {
        let spec = self.spec(EncodeOptions {
            method,
            ablation,
            population_decoys: 0,
            near_pupil_decoys: 0,
            decoy: DecoyKind::Image,
            max_iterations,
            sub_rays: 16,
            optics: self.optics,
            // The paper's Eq. 14: every observer at the target's weight, nothing else.
            decoy_weight: Some(1.0),
            leak_weight: 0.0,
            ensure_target_reads: false,
            seed: Some(crate::research::EXPERIMENT_SEED),
            ..Default::default()
        });
        let t = Instant::now();
        let enc = encode(&spec, &self.cache, &|_| {}, &AtomicBool::new(false))?;
        let timing = format!(
            "Fig. {fig} {variant}: {:.1} s, {} iterations",
            t.elapsed().as_secs_f64(),
            enc.solver.iterations
        );
        let tiles = self.score_all(fig, variant, &enc.light_field, rows);
        let file = format!("fig{fig}_{}.png", variant.replace(' ', "_"));
        save(&strip(&tiles), out, &file)?;
        Ok(timing)
    }

    /// The population's view of the proposed multiplex encoding (not in the paper, which had three observers):
    /// writes `fig14_population/` and appends its summary line to `md`.
    fn population_check(&self, out: &Path, max_iterations: u32, population: u32, md: &mut String) -> Result<()> {
        let spec = self.spec(EncodeOptions {
            method: Method::Multiplex,
            population_decoys: 0,
            near_pupil_decoys: 0,
            max_iterations,
            decoy: DecoyKind::Image,
            optics: self.optics,
            decoy_weight: Some(1.0),
            leak_weight: 0.0,
            ensure_target_reads: false,
            seed: Some(crate::research::EXPERIMENT_SEED),
            ..Default::default()
        });
        let cancel = AtomicBool::new(false);
        let enc = encode(&spec, &self.cache, &|_| {}, &cancel)?;
        let ev = evaluate(
            &self.display,
            &enc.light_field,
            &self.document,
            OBJECTIVE_LEVEL,
            &self.observers[0].1,
            &[],
            &EvaluationOptions {
                population,
                key_directions: 0,
                head_offsets_mm: vec![],
                optics: self.optics,
                ..Default::default()
            },
            &self.cache,
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
                camera_best(&ev.report)
            )?;
        }
        eyekey_core::encoding::pipeline::write_evaluation(&ev, &out.join("fig14_population"))?;
        Ok(())
    }
}

/// The camera attacker's best legibility (0 when no camera was tried).
fn camera_best(report: &Report) -> f64 {
    report.camera.as_ref().map_or(0.0, |c| c.best.legibility)
}

/// The §7.3 results table: one line per (figure, encoding, observer).
fn paper_table(rows: &[Row]) -> Result<String> {
    let mut md = table_header(&[
        "figure",
        "encoding",
        "observer",
        "legibility",
        "NCC",
        "PSNR (dB)",
        "SSIM",
        "readable",
    ]);
    for r in rows {
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
    Ok(md)
}

/// Creates the output directory `out`.
fn create_out(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))
}

/// Reproduces the paper's §7.3 (Figs. 13–15) on the `paper` preset under `optics`; writes pictures and
/// `results.md`.
pub fn paper(out: &Path, max_iterations: u32, population: u32, optics: Optics) -> Result<String> {
    create_out(out)?;
    let setup = PaperSetup::new(out, optics)?;
    let mut rows = Vec::new();
    // Fig. 13: the document on a plain 2D display.
    let plain = plain_light_field_for_image(&setup.display, &setup.document);
    let tiles = setup.score_all("13", "plain 2D display", &plain, &mut rows);
    save(&strip(&tiles), out, "fig13_plain.png")?;
    // Figs. 14 and 15: each encoder, proposed and with either key ablated.
    let mut timings = Vec::new();
    for figure in [("14", Method::Multiplex), ("15", Method::Diffmax)] {
        for variant in [
            ("proposed", None),
            ("optical only", Some(Ablation::Optical)),
            ("spectral only", Some(Ablation::Spectral)),
        ] {
            timings.push(setup.figure_variant(out, figure, variant, max_iterations, &mut rows)?);
        }
    }
    let mut md = format!("Forward model of the encoders and of every viewer: {optics:?} optics.\n\n");
    md.push_str(&paper_table(&rows)?);
    if population > 0 {
        setup.population_check(out, max_iterations, population, &mut md)?;
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
    pub display: DisplayGeometry,
    /// Forward model of the encoder and of every viewer.
    pub optics: Optics,
    /// The display's smallest resolvability M = A·s/(λd) over its bands (views resolved while ≥ 1).
    pub resolvability: f64,
    /// Viewing pupil of the target, mm.
    pub pupil_mm: f64,
    /// Decoy observers K − 1.
    pub decoys: u32,
    /// Decoy strategy.
    pub decoy: DecoyKind,
    pub decoy_weight: f64,
    pub target_legibility: f64,
    /// Whether the known-font attacker reads the target's view.
    pub target_known_font: bool,
    /// Fraction of the sampled population that can read (the known-font attacker's judgement: the sweep's
    /// document text is known).
    pub readable_fraction: f64,
    /// Fraction the known-font attacker reads.
    pub known_font_fraction: f64,
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
        aperture: Default::default(),
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

/// A lenslet display for the wave sweep: `holes`² square lenslets of side and aperture `pitch_mm`, `views`² views `spacing_mm` apart at `distance_mm`; the focal length follows,
/// f = p_s·d/s with p_s = pitch/views.
pub(crate) fn sweep_lenslet(
    holes: u32,
    pitch_mm: f64,
    views: u32,
    spacing_mm: f64,
    distance_mm: f64,
) -> DisplayGeometry {
    let p_s = pitch_mm / views as f64;
    DisplayGeometry {
        holes_x: holes,
        holes_y: holes,
        hole_pitch_mm: pitch_mm,
        hole_diameter_mm: pitch_mm,
        views_u: views,
        views_v: views,
        screen_pixel_pitch_mm: p_s,
        gap_mm: p_s * distance_mm / spacing_mm,
        viewing_distance_mm: distance_mm,
        ..DisplayGeometry::lenslet()
    }
}

/// A pinhole barrier for the wave sweep: `holes`² holes of `hole_mm` at `pitch_mm`, `views`² screen pixels of
/// pitch/views behind each, `gap_mm` deep, viewed from `distance_mm`.
fn sweep_pinhole(
    holes: u32,
    pitch_mm: f64,
    hole_mm: f64,
    views: u32,
    gap_mm: f64,
    distance_mm: f64,
) -> DisplayGeometry {
    DisplayGeometry {
        holes_x: holes,
        holes_y: holes,
        hole_pitch_mm: pitch_mm,
        hole_diameter_mm: hole_mm,
        views_u: views,
        views_v: views,
        screen_pixel_pitch_mm: pitch_mm / views as f64,
        gap_mm,
        viewing_distance_mm: distance_mm,
        ..DisplayGeometry::pinhole()
    }
}

/// One configuration of the design-space sweep: what differs from the baseline.
struct SweepConfig {
    label: String,
    display: DisplayGeometry,
    /// Viewing pupil of the target, mm.
    pupil_mm: f64,
    /// Population decoys K − 1.
    decoys: u32,
    decoy: DecoyKind,
    decoy_weight: f64,
    adaptive_rounds: u32,
    optics: Optics,
}

impl SweepConfig {
    /// The baseline: 7×7 views, 0.3 mm pitch, 500 mm, 32×32 holes, 4 bands, 6 mm pupil, 6 noise decoys w=0.3.
    fn base(label: &str) -> Self {
        Self {
            label: label.to_string(),
            display: sweep_display(7, 0.3, 500.0, 32, 4),
            pupil_mm: 6.0,
            decoys: 6,
            decoy: DecoyKind::Noise,
            decoy_weight: 0.3,
            adaptive_rounds: 0,
            optics: Optics::Geometric,
        }
    }

    /// The wave sweep's baseline: a 32×32 lenslet display of 1 mm lenslets, 9×9 views 0.6 mm apart at 500 mm
    /// (the `lenslet` preset on a smaller array), 6 mm pupil, 6 noise decoys at weight 0.3.
    fn wave_base(label: &str) -> Self {
        Self {
            display: sweep_lenslet(32, 1.0, 9, 0.6, 500.0),
            optics: Optics::Wave,
            ..Self::base(label)
        }
    }

    /// The wave baseline on another display.
    fn wave_on(label: &str, display: DisplayGeometry) -> Self {
        Self {
            display,
            ..Self::wave_base(label)
        }
    }

    /// The baseline with another display.
    fn on(label: &str, display: DisplayGeometry) -> Self {
        Self {
            display,
            ..Self::base(label)
        }
    }

    /// The baseline with other decoys (and display).
    fn decoys(label: &str, display: DisplayGeometry, decoys: u32, decoy_weight: f64, adaptive_rounds: u32) -> Self {
        Self {
            display,
            decoys,
            decoy_weight,
            adaptive_rounds,
            ..Self::base(label)
        }
    }
}

/// The sweep's configurations, in the order they run: the baseline, then one axis varied at a time.
fn sweep_configs() -> Vec<SweepConfig> {
    let d = |views: u32, pitch_mm: f64, distance_mm: f64, bands: usize| {
        sweep_display(views, pitch_mm, distance_mm, 32, bands)
    };
    let mut configs = vec![SweepConfig::base(
        "baseline: 7×7 views, 0.3 mm, 500 mm, 4 bands, 6 noise decoys w=0.3",
    )];
    for v in [3u32, 5, 9] {
        configs.push(SweepConfig::on(&format!("views {v}×{v}"), d(v, 0.3, 500.0, 4)));
    }
    for p in [4.0, 5.0] {
        configs.push(SweepConfig {
            pupil_mm: p,
            ..SweepConfig::base(&format!("pupil {p} mm"))
        });
    }
    for dist in [350.0, 700.0] {
        configs.push(SweepConfig::on(
            &format!("viewing distance {dist} mm"),
            d(7, 0.3, dist, 4),
        ));
    }
    for pitch in [0.2, 0.45] {
        configs.push(SweepConfig::on(
            &format!("hole pitch {pitch} mm"),
            d(7, pitch, 500.0, 4),
        ));
    }
    configs.push(SweepConfig::on("3 bands", d(7, 0.3, 500.0, 3)));
    for (k, w) in [(0u32, 0.3), (2, 0.3), (12, 0.3), (12, 0.15), (6, 0.6), (24, 0.1)] {
        let label = format!("K−1 = {k} decoys, weight {w}");
        configs.push(SweepConfig::decoys(&label, d(7, 0.3, 500.0, 4), k, w, 0));
    }
    configs.push(SweepConfig {
        decoy: DecoyKind::Grey,
        ..SweepConfig::base("grey decoys")
    });
    configs.push(SweepConfig::decoys(
        "9×9 views, 12 decoys w=0.2",
        d(9, 0.3, 500.0, 4),
        12,
        0.2,
        0,
    ));
    configs.push(SweepConfig::decoys(
        "9×9 views, 12 decoys w=0.2, 2 adaptive rounds",
        d(9, 0.3, 500.0, 4),
        12,
        0.2,
        2,
    ));
    configs.push(SweepConfig::decoys(
        "7×7 views, 6 decoys w=0.3, 2 adaptive rounds",
        d(7, 0.3, 500.0, 4),
        6,
        0.3,
        2,
    ));
    configs
}

/// The wave-optics sweep: the lenslet baseline, then one axis at a time (aperture kind, pitch, aperture, gap,
/// views, viewing distance, pupil, decoys), and the geometric sweep's diffraction-limited baseline for contrast.
fn wave_sweep_configs() -> Vec<SweepConfig> {
    let l = |pitch: f64, views: u32, spacing: f64, distance: f64| sweep_lenslet(32, pitch, views, spacing, distance);
    let mut configs = vec![SweepConfig::wave_base(
        "baseline: lenslet 1 mm, 9×9 views 0.6 mm apart (f 92.6 mm), 500 mm, 6 noise decoys w=0.3",
    )];
    // Aperture kind: the `pinhole` preset's barrier, a pinhole barrier as dense in angle as the lenslets, and the
    // geometric sweep's baseline (43 µm holes), all on 32×32 apertures.
    configs.push(SweepConfig::wave_on(
        "pinhole barrier: 0.15 mm holes at 0.75 mm, 5×5 views 2.5 mm apart (gap 30 mm)",
        sweep_pinhole(32, 0.75, 0.15, 5, 30.0, 500.0),
    ));
    configs.push(SweepConfig::wave_on(
        "pinhole barrier: 0.11 mm holes at 1 mm, 9×9 views 0.6 mm apart (gap 92.6 mm)",
        sweep_pinhole(32, 1.0, 1.0 / 9.0, 9, 92.6, 500.0),
    ));
    configs.push(SweepConfig::wave_on(
        "geometric sweep's baseline: 43 µm holes at 0.3 mm, 7×7 views 0.94 mm apart",
        sweep_display(7, 0.3, 500.0, 32, 4),
    ));
    // Pitch (aperture = pitch), at the same views and view spacing.
    for pitch in [0.7, 1.4] {
        configs.push(SweepConfig::wave_on(
            &format!("lenslet pitch {pitch} mm"),
            l(pitch, 9, 0.6, 500.0),
        ));
    }
    // Aperture: a lenslet's aperture is its cell (its views must fit behind it), so the aperture is varied on
    // the pinhole barrier: smaller holes diffract more, larger ones blur neighbouring screen pixels together.
    for hole in [0.1, 0.25] {
        configs.push(SweepConfig::wave_on(
            &format!("pinhole barrier, holes {hole} mm"),
            sweep_pinhole(32, 0.75, hole, 5, 30.0, 500.0),
        ));
    }
    // Gap (focal length), which sets the view spacing at the pupil.
    for spacing in [0.4, 0.9] {
        let f = 1.0 / 9.0 * 500.0 / spacing;
        configs.push(SweepConfig::wave_on(
            &format!("focal length {f:.0} mm (views {spacing} mm apart)"),
            l(1.0, 9, spacing, 500.0),
        ));
    }
    // Views behind each lenslet, at the same spacing.
    for v in [5u32, 7, 13] {
        configs.push(SweepConfig::wave_on(&format!("views {v}×{v}"), l(1.0, v, 0.6, 500.0)));
    }
    // Viewing distance at the same focal length: the spacing scales with d, M does not.
    for dist in [350.0, 700.0] {
        configs.push(SweepConfig::wave_on(
            &format!("viewing distance {dist} mm"),
            l(1.0, 9, 0.6 * dist / 500.0, dist),
        ));
    }
    for p in [4.0, 5.0] {
        configs.push(SweepConfig {
            pupil_mm: p,
            ..SweepConfig::wave_base(&format!("pupil {p} mm"))
        });
    }
    for (k, w) in [(0u32, 0.3), (12, 0.2)] {
        configs.push(SweepConfig {
            decoys: k,
            decoy_weight: w,
            ..SweepConfig::wave_base(&format!("K−1 = {k} decoys, weight {w}"))
        });
    }
    configs
}

/// The sampled target of the sweep and the `secure` experiment (seed 4242, no pupil spread).
pub(crate) fn sampled_target() -> VisionProfile {
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(4242);
    eyekey_core::physics::population::sample_person(
        &mut rng,
        eyekey_core::physics::population::SamplingScope {
            pupil_spread: false,
            ..Default::default()
        },
    )
}

/// `target` viewing through a pupil of `pupil_mm`: its Zernike terms rescaled when the pupil is smaller.
fn at_pupil(target: &VisionProfile, pupil_mm: f64) -> Result<VisionProfile> {
    let mut tgt = target.clone();
    if pupil_mm < tgt.pupil_diameter_mm {
        let z = eyekey_core::physics::zernike::ZernikeCoefficients::new(tgt.pupil_diameter_mm, tgt.zernike_um.clone())?;
        tgt.zernike_um = z.rescaled(pupil_mm)?.coefficients_um;
        tgt.pupil_diameter_mm = pupil_mm;
    }
    Ok(tgt)
}

/// The sweep's encoding job for one configuration (12 sub-rays, seed 5).
fn sweep_spec(c: &SweepConfig, target: &VisionProfile, document: &RgbImage, max_iterations: u32) -> JobSpec {
    JobSpec {
        display: c.display.clone(),
        target: target.clone(),
        target_label: "sweep".into(),
        observers: vec![],
        document: document.clone(),
        decoy: None,
        options: EncodeOptions {
            population_decoys: c.decoys,
            near_pupil_decoys: 0,
            decoy: c.decoy,
            decoy_weight: Some(c.decoy_weight),
            max_iterations,
            sub_rays: 12,
            seed: Some(5),
            adaptive_rounds: c.adaptive_rounds,
            adaptive_candidates: 32,
            adaptive_per_round: 6,
            optics: c.optics,
            leak_weight: 0.0,
            ensure_target_reads: false,
            ..Default::default()
        },
    }
}

/// The sweep's evaluation: the population and a small camera grid; no key or head-movement checks.
fn sweep_evaluation_options(population: u32, optics: Optics, document_width: u32) -> EvaluationOptions {
    EvaluationOptions {
        population,
        optics,
        document_text: Some(pin_slip_text(document_width)),
        sub_rays: 12,
        key_directions: 0,
        head_offsets_mm: vec![],
        camera_focus_d: vec![-1.0, 0.0, 1.0],
        camera_apertures_mm: vec![2.0, 6.0],
        ..Default::default()
    }
}

/// Encodes and evaluates one configuration; logs its line on stderr.
fn sweep_point(
    c: SweepConfig,
    target: &VisionProfile,
    population: u32,
    max_iterations: u32,
    cache: &TransportCache,
) -> Result<SweepPoint> {
    let t = Instant::now();
    let cancel = AtomicBool::new(false);
    let g = (c.display.holes_x * 4, c.display.holes_y * 4);
    let document = pin_slip(g.0, g.1);
    let tgt = at_pupil(target, c.pupil_mm)?;
    let spec = sweep_spec(&c, &tgt, &document, max_iterations);
    let enc = encode(&spec, cache, &|_| {}, &cancel)?;
    let options = sweep_evaluation_options(population, c.optics, g.0);
    let ev = evaluate(
        &c.display,
        &enc.light_field,
        &document,
        OBJECTIVE_LEVEL,
        &tgt,
        &[],
        &options,
        cache,
        &|_| {},
        &cancel,
    )?;
    let p = ev.report.population.as_ref().context("population evaluated")?;
    let resolvability = eyekey_core::physics::resolvability::Resolvability::of(&c.display)
        .bands
        .iter()
        .map(|b| b.resolvability)
        .fold(f64::INFINITY, f64::min);
    let point = SweepPoint {
        label: c.label,
        display: c.display,
        optics: c.optics,
        resolvability,
        pupil_mm: c.pupil_mm,
        decoys: c.decoys,
        decoy: c.decoy,
        decoy_weight: c.decoy_weight,
        target_legibility: ev.report.target.legibility,
        target_known_font: ev.report.target.known_font.as_ref().is_some_and(|k| k.correct),
        readable_fraction: p.readable_fraction,
        known_font_fraction: p.known_font_readers.unwrap_or(0) as f64 / p.count.max(1) as f64,
        p95_legibility: p.p95_legibility,
        camera_best: camera_best(&ev.report),
        seconds: t.elapsed().as_secs_f64(),
    };
    eprintln!(
        "{:<60} M {:.2}  target {:.2} (known font: {})  readable {:>5.1} % (known font {:>5.1} %)  p95 {:.2}  camera {:.2}  ({:.1} s)",
        point.label,
        point.resolvability,
        point.target_legibility,
        if point.target_known_font { "read" } else { "not read" },
        100.0 * point.readable_fraction,
        100.0 * point.known_font_fraction,
        point.p95_legibility,
        point.camera_best,
        point.seconds
    );
    Ok(point)
}

/// The frontier: points not dominated in (high target legibility, low readable fraction).
fn pareto_frontier(points: &[SweepPoint]) -> Vec<&SweepPoint> {
    points
        .iter()
        .filter(|a| {
            !points.iter().any(|b| {
                b.target_legibility >= a.target_legibility
                    && b.readable_fraction <= a.readable_fraction
                    && (b.target_legibility > a.target_legibility || b.readable_fraction < a.readable_fraction)
            })
        })
        .collect()
}

/// The sweep's Markdown: the table of all points, the Pareto frontier and, under geometric optics, the point
/// the `dense` preset was chosen as; under wave optics, the point with the fewest readers among those the target
/// reads.
fn sweep_markdown(points: &[SweepPoint], optics: Optics) -> Result<String> {
    let mut md = format!(
        "Forward model of the encoders and of every viewer: {optics:?} optics. Resolvability M is the smallest \
         over the bands (views resolved while M ≥ 1; `eyekey display check`). The PIN slip's text is known, so a \
         person reads when the known-font attacker (a matched filter per digit, `evaluation::known_font`) reads \
         all four digits; legibility is the continuous figure.\n\n"
    );
    md += &table_header(&[
        "configuration",
        "resolvability M",
        "target legibility",
        "known-font attacker reads the target",
        "population readable",
        "read by the known-font attacker",
        "population p95",
        "camera best",
        "seconds",
    ]);
    for p in points {
        writeln!(
            md,
            "| {} | {:.2} | {:.2} | {} | {:.1} % | {:.1} % | {:.2} | {:.2} | {:.1} |",
            p.label,
            p.resolvability,
            p.target_legibility,
            if p.target_known_font { "yes" } else { "no" },
            100.0 * p.readable_fraction,
            100.0 * p.known_font_fraction,
            p.p95_legibility,
            p.camera_best,
            p.seconds
        )?;
    }
    let frontier = pareto_frontier(points);
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
    if optics == Optics::Wave {
        match points
            .iter()
            .filter(|p| p.target_known_font)
            .min_by(|a, b| a.readable_fraction.total_cmp(&b.readable_fraction))
        {
            Some(best) => writeln!(
                md,
                "\nFewest readers among points where the known-font attacker reads the target: **{}** (target {:.2}, readable {:.1} %).",
                best.label,
                best.target_legibility,
                100.0 * best.readable_fraction
            )?,
            None => writeln!(md, "\nThe known-font attacker reads the target at no point.")?,
        }
        return Ok(md);
    }
    // Under geometric optics the `dense` preset was chosen from the frontier: the fewest readers among points
    // where the target reads with legibility ≥ 0.85.
    if let Some(best) = frontier
        .iter()
        .filter(|p| p.target_legibility >= 0.85)
        .min_by(|a, b| a.readable_fraction.total_cmp(&b.readable_fraction))
    {
        writeln!(
            md,
            "\nChosen for the `dense` preset (fewest readers with target legibility ≥ 0.85): **{}** (target {:.2}, readable {:.1} %).",
            best.label,
            best.target_legibility,
            100.0 * best.readable_fraction
        )?;
    }
    Ok(md)
}

/// Maps the design space to (target legibility, fraction of a sampled population that can read).
/// Under geometric optics the configurations are the ones the `dense` preset was chosen from; under wave
/// optics, displays that resolve their views (`wave_sweep_configs`).
pub fn sweep(out: &Path, population: u32, max_iterations: u32, optics: Optics) -> Result<(String, Vec<SweepPoint>)> {
    create_out(out)?;
    let cache = TransportCache::default();
    let target = sampled_target();
    let configs = match optics {
        Optics::Geometric => sweep_configs(),
        Optics::Wave => wave_sweep_configs(),
    };
    // Every display is checked before the first one runs, so a bad configuration does not cost the others.
    for c in &configs {
        c.display
            .validate()
            .with_context(|| format!("sweep configuration \"{}\"", c.label))?;
    }
    let points = configs
        .into_iter()
        .map(|c| sweep_point(c, &target, population, max_iterations, &cache))
        .collect::<Result<Vec<_>>>()?;
    let md = sweep_markdown(&points, optics)?;
    std::fs::write(out.join("sweep.md"), &md)?;
    std::fs::write(out.join("sweep.json"), serde_json::to_string_pretty(&points)?)?;
    Ok((md, points))
}

/// Encodes the `secure` job, replacing `out/bundle`; returns the encoding and its seconds.
fn secure_encode(spec: &JobSpec, out: &Path, cache: &TransportCache) -> Result<(Encoded, f64)> {
    let cancel = AtomicBool::new(false);
    let t = Instant::now();
    let enc = encode(spec, cache, &|_| {}, &cancel)?;
    let t_encode = t.elapsed().as_secs_f64();
    let bundle = out.join("bundle");
    if bundle.exists() {
        std::fs::remove_dir_all(&bundle)?;
    }
    eyekey_core::encoding::pipeline::write_outputs(spec, &enc, &bundle, false, cache, &|_| {}, &cancel)?;
    Ok((enc, t_encode))
}

/// Evaluates the `secure` encoding against `population` people, a camera, key sensitivity (4 directions)
/// and head movement; writes `out/evaluation`; returns the evaluation and its seconds.
fn secure_evaluate(
    spec: &JobSpec,
    enc: &Encoded,
    population: u32,
    out: &Path,
    cache: &TransportCache,
) -> Result<(Evaluation, f64)> {
    let t = Instant::now();
    let ev = evaluate(
        &spec.display,
        &enc.light_field,
        &spec.document,
        OBJECTIVE_LEVEL,
        &spec.target,
        &[],
        &EvaluationOptions {
            population,
            key_directions: 4,
            document_text: enc.document_text.clone(),
            camera_focus_d: eyekey_core::evaluation::BystanderOptions::default().camera_focus_d,
            camera_apertures_mm: eyekey_core::evaluation::BystanderOptions::default().camera_apertures_mm,
            ..Default::default()
        },
        cache,
        &|_| {},
        &AtomicBool::new(false),
    )?;
    let t_eval = t.elapsed().as_secs_f64();
    eyekey_core::encoding::pipeline::write_evaluation(&ev, &out.join("evaluation"))?;
    Ok((ev, t_eval))
}

/// The `secure` table's first rows: the display, the encoder and the target's scores.
fn secure_setup_rows(md: &mut String, spec: &JobSpec, enc: &Encoded, r: &Report) -> Result<()> {
    let (display, options) = (&spec.display, &spec.options);
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
        "| encoder | multiplex, {} population decoys (noise masks), {} near-pupil decoys, decoy weight {}, leak weight {}, {} adaptive rounds, camera decoys: {}, decoy weights finally scaled by {:.3} |",
        options.population_decoys,
        options.near_pupil_decoys,
        options.decoy_weight_on(display),
        options.leak_weight,
        options.adaptive_rounds,
        options.camera_decoys,
        enc.solver.decoy_weight_scale
    )?;
    writeln!(
        md,
        "| target legibility / PSNR / SSIM | {:.2} / {:.1} dB / {:.2}; the known-font attacker reads it: {} |",
        r.target.legibility,
        r.target.psnr_db,
        r.target.ssim,
        r.target
            .known_font
            .as_ref()
            .map(|k| format!("{} (\"{}\")", if k.correct { "yes" } else { "**no**" }, k.text))
            .unwrap_or_else(|| "–".into())
    )?;
    Ok(())
}

/// The `secure` table's population rows.
fn secure_population_rows(md: &mut String, p: &PopulationSummary) -> Result<()> {
    writeln!(
        md,
        "| sampled people who read (the known-font attacker or the learned reader, at any focus from −1 to +2 D) | {} of {} ({:.1} %, 95 % interval {:.1}–{:.1} %); with at most one digit wrong: {} |",
        p.readable_count,
        p.count,
        100.0 * p.readable_fraction,
        100.0 * p.readable_ci95.0,
        100.0 * p.readable_ci95.1,
        p.known_font_all_but_one
            .map(|n| n.to_string())
            .unwrap_or_else(|| "–".into())
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
    Ok(())
}

/// The `secure` table's attacker rows: camera, key sensitivity, head movement (each when evaluated).
fn secure_attacker_rows(md: &mut String, r: &Report) -> Result<()> {
    if let Some(c) = &r.camera {
        writeln!(
            md,
            "| camera attacker's best | {:.2}{} ({}); settings that read: {} of {} |",
            c.best.legibility,
            c.best
                .known_font
                .as_ref()
                .map(|_| format!(", known font {}", super::known_font_cell(&c.best)))
                .unwrap_or_default(),
            c.best.label,
            c.tried.iter().filter(|s| s.readable).count(),
            c.tried.len()
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
    Ok(())
}

/// Encodes a PIN slip for a sampled target on the `secure` preset and evaluates it against `population`
/// sampled people, a camera attacker, key sensitivity and head movement.
pub fn secure(out: &Path, population: u32) -> Result<String> {
    create_out(out)?;
    let cache = TransportCache::default();
    let display = DisplayGeometry::secure();
    let target = sampled_target();
    std::fs::write(
        out.join("target_profile_example.json"),
        serde_json::to_string_pretty(&target)?,
    )?;
    let g = (display.holes_x * 4, display.holes_y * 4);
    let spec = JobSpec {
        display,
        target,
        target_label: "secure experiment".into(),
        observers: vec![],
        document: pin_slip(g.0, g.1),
        decoy: None,
        // The default options (the encoder frontier's, docs/experiments.md §2d) and the slip's text hint.
        options: EncodeOptions {
            document_text: Some(pin_slip_text(g.0)),
            seed: Some(crate::research::EXPERIMENT_SEED),
            ..Default::default()
        },
    };
    let (enc, t_encode) = secure_encode(&spec, out, &cache)?;
    let (ev, t_eval) = secure_evaluate(&spec, &enc, population, out, &cache)?;
    let r = &ev.report;
    let mut md = table_header(&["quantity", "value"]);
    secure_setup_rows(&mut md, &spec, &enc, r)?;
    if let Some(p) = &r.population {
        secure_population_rows(&mut md, p)?;
    }
    secure_attacker_rows(&mut md, r)?;
    writeln!(md, "| encode / evaluation time | {t_encode:.1} s / {t_eval:.1} s |")?;
    std::fs::write(out.join("results.md"), &md)?;
    Ok(md)
}
