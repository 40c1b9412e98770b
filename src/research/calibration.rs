//! Views for calibrating the legibility threshold against OCR (`eyekey experiment calibrate`).
//!
//! Every view shows a random 4-digit PIN and spans the range from plainly legible to unreadable:
//!
//! - `plain`: the PIN on an ordinary 2D display, seen by sampled people with an uncorrected defocus of up to
//!   ±2 D (blurred but often legible);
//! - `target`, `person`, `camera`: the PIN encoded by the multiplex encoder with 0, 2, 6 or 12 population
//!   decoys of weight 0.1, 0.3 or 1.0, seen by its target, by people sampled from the population statistics,
//!   and by an ideal camera-like eye (standard cones, 4 mm aperture) focused within ±1 D.
//!
//! Each view is scored with [`eyekey_core::evaluation::Reference::score`] (legibility and plain NCC) and written as
//! the picture an attacker would start from: luminance stretched to 0..255, upscaled ×4 (bilinear), 8-bit
//! grey. `views.csv` lists `file,text,legibility,ncc,kind`; `benches/calibrate_ocr.sh` OCRs them.

use eyekey_core::physics::transport::TransportCache;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use image::{GrayImage, Luma, RgbImage};
use rand::{Rng, SeedableRng};

use eyekey_core::encoding::pipeline::{encode, DecoyKind, EncodeOptions, JobSpec, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{luminance, stretch_to_unit, Reference, DEFAULT_THRESHOLD};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer, Optics};
use eyekey_core::physics::population::{sample_person, SamplingScope};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportOptions};
use eyekey_core::physics::zernike::Prescription;

/// Upscaling factor of the written views.
pub const UPSCALE: u32 = 4;

/// How the calibration views are made.
#[derive(Clone, Debug)]
struct Setup {
    display: DisplayGeometry,
    /// Sub-rays of the encoder's operators.
    sub_rays: u32,
    /// Sub-rays of the viewers' operators (with their own jitter seed).
    view_sub_rays: u32,
    max_iterations: u32,
    /// Population decoys of the encodings (cycled together with `weights`).
    decoys: Vec<u32>,
    /// Decoy weights.
    weights: Vec<f64>,
    /// Sampled people looking at each encoding.
    people_per_encoding: usize,
    /// Camera-like views of each encoding.
    cameras_per_encoding: usize,
    /// Sampled people kept in the viewing pool (their operators are reused between encodings).
    pool: usize,
}

impl Setup {
    fn standard() -> Self {
        Self {
            // 56×56 holes: a line of four 5×7 digits at two pixels per font dot (48 pixels) fits with a margin.
            display: DisplayGeometry {
                aperture: Default::default(),
                holes_x: 56,
                holes_y: 56,
                ..DisplayGeometry::secure()
            },
            sub_rays: 8,
            view_sub_rays: 12,
            max_iterations: 100,
            decoys: vec![0, 2, 6, 12],
            weights: vec![0.1, 0.3, 1.0],
            people_per_encoding: 10,
            cameras_per_encoding: 2,
            pool: 30,
        }
    }
}

/// The document: one line of four digits, black on white, on the retinal grid (one pixel per hole) at
/// `scale` pixels per font dot.
pub fn pin_document(pin: &str, width: u32, height: u32, scale: u32) -> RgbImage {
    eyekey_core::imaging::glyphs::render_text(&[pin], width, height, scale)
}

/// Writes `count` views with known text and their legibility into `out_dir` (`view_<k>.png`, `views.csv`).
pub fn calibration_views(out_dir: &Path, count: usize, seed: u64) -> Result<()> {
    views_with(out_dir, count, seed, &Setup::standard())
}

struct View {
    text: String,
    legibility: f64,
    ncc: f64,
    kind: String,
    luminance: Vec<f32>,
}

/// The attacker's starting picture: luminance stretched to its own range, upscaled, 8-bit grey.
fn attacker_picture(lum: &[f32], width: u32, height: u32) -> GrayImage {
    let stretched = stretch_to_unit(lum);
    let small = GrayImage::from_fn(width, height, |x, y| {
        let v = stretched[(y * width + x) as usize];
        Luma([(v.clamp(0.0, 1.0) * 255.0).round() as u8])
    });
    image::imageops::resize(
        &small,
        width * UPSCALE,
        height * UPSCALE,
        image::imageops::FilterType::Triangle,
    )
}

fn random_pin<R: Rng>(rng: &mut R) -> String {
    format!("{:04}", rng.gen_range(0..10_000u32))
}

/// Writes the views as they come: `view_<k>.png` each, and the lines of `views.csv`.
struct ViewWriter<'a> {
    out_dir: &'a Path,
    /// Retinal grid of the views.
    width: u32,
    height: u32,
    /// Views written so far.
    written: usize,
    csv: String,
}

impl<'a> ViewWriter<'a> {
    fn new(out_dir: &'a Path, width: u32, height: u32) -> Self {
        Self {
            out_dir,
            width,
            height,
            written: 0,
            csv: String::from("file,text,legibility,ncc,kind\n"),
        }
    }

    /// Saves the view's attacker picture as the next `view_<k>.png` and adds its line to the table.
    fn push(&mut self, v: View) -> Result<()> {
        let file = format!("view_{}.png", self.written);
        attacker_picture(&v.luminance, self.width, self.height)
            .save(self.out_dir.join(&file))
            .with_context(|| format!("writing {file}"))?;
        writeln!(
            self.csv,
            "{file},{},{:.6},{:.6},{}",
            v.text, v.legibility, v.ncc, v.kind
        )?;
        self.written += 1;
        Ok(())
    }

    /// Writes `views.csv`.
    fn finish(self) -> Result<()> {
        std::fs::write(self.out_dir.join("views.csv"), self.csv).context("writing views.csv")
    }
}

/// Scores what observer `o` sees of light field `l` against `doc`: (legibility, NCC, the view's luminance).
fn score(doc: &RgbImage, o: &Observer, l: &[f32]) -> (f64, f64, Vec<f32>) {
    let g = o.grid();
    let reference = Reference::new(doc, g.width, g.height, OBJECTIVE_LEVEL, DEFAULT_THRESHOLD);
    let lum = luminance(&o.view(l));
    let white = 0.689_902_7 * o.white[0] + 0.348_321_9 * o.white[1];
    let s = reference.score("", &lum, white);
    (s.legibility, s.ncc, lum)
}

/// What every view of one calibration run shares.
struct Views<'a> {
    setup: &'a Setup,
    seed: u64,
    cache: TransportCache,
    /// The viewers' transport options: the evaluation's own sub-ray jitter, different from every encoder's.
    topts: TransportOptions,
    /// Text sizes, pixels per font dot.
    scales: Vec<u32>,
    /// Sampled people who look at the encodings.
    pool: Vec<VisionProfile>,
    /// (decoys, weight) combinations of the encodings, visited `stride` apart (a stride coprime to their
    /// number, so all are visited).
    combos: Vec<(u32, f64)>,
    stride: usize,
    cancel: AtomicBool,
    started: Instant,
}

impl<'a> Views<'a> {
    /// Prepares a run; draws the viewing pool from `rng`.
    fn new(setup: &'a Setup, seed: u64, rng: &mut impl Rng) -> Self {
        let started = Instant::now();
        let topts = TransportOptions {
            sub_rays: setup.view_sub_rays,
            seed: seed ^ 0xCA11_B8A7,
            ..Default::default()
        };
        // Two text sizes: digits filling the width but for a margin (2 px per font dot where the grid allows)
        // and the dense 1 px per dot of the experiments' PIN slips.
        let big = (setup.display.holes_x.saturating_sub(4) / 24).max(1);
        let scales = if big > 1 { vec![big, 1] } else { vec![1] };
        let pool = (0..setup.pool.max(1))
            .map(|_| sample_person(&mut *rng, SamplingScope::default()))
            .collect();
        let combos: Vec<(u32, f64)> = setup
            .decoys
            .iter()
            .flat_map(|&k| setup.weights.iter().map(move |&w| (k, w)))
            .collect();
        let stride = (combos.len() / 3 + 1..combos.len())
            .find(|s| gcd(*s, combos.len()) == 1)
            .unwrap_or(1);
        Self {
            setup,
            seed,
            cache: TransportCache::default(),
            topts,
            scales,
            pool,
            combos,
            stride,
            cancel: AtomicBool::new(false),
            started,
        }
    }

    /// A viewer's operator on the display.
    fn observer(&self, person: &VisionProfile) -> Result<Observer> {
        Ok(Observer::new(
            &self.setup.display,
            person,
            EyePosition::default(),
            &self.topts,
            Optics::Geometric,
            &self.cache,
        )?)
    }

    /// View `k` of the plain display: a sampled person with an uncorrected defocus (more of them near focus).
    fn plain_view(&self, k: usize, rng: &mut impl Rng) -> Result<View> {
        let d = &self.setup.display;
        let pin = random_pin(rng);
        let scale = self.scales[k % self.scales.len()];
        let doc = pin_document(&pin, d.holes_x, d.holes_y, scale);
        let mut person = sample_person(&mut *rng, SamplingScope::default());
        let u: f64 = rng.gen_range(-1.0..=1.0);
        let defocus = 2.0 * u * u.abs();
        person.prescription = Some(Prescription {
            sphere_d: defocus,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        });
        let o = self.observer(&person)?;
        let (legibility, ncc, luminance) = score(&doc, &o, &plain_light_field_for_image(d, &doc));
        let kind = format!(
            "plain defocus={defocus:+.2}D pupil={:.1}mm scale={scale}",
            person.pupil_diameter_mm
        );
        Ok(View {
            text: pin,
            legibility,
            ncc,
            kind,
            luminance,
        })
    }

    /// Encodes document `doc` for `target` with `decoys` noise decoys of `weight` (view set `e`).
    fn encode(&self, e: usize, doc: &RgbImage, target: &VisionProfile, decoys: u32, weight: f64) -> Result<Vec<f32>> {
        let spec = JobSpec {
            display: self.setup.display.clone(),
            target: target.clone(),
            target_label: "calibration".into(),
            observers: vec![],
            document: doc.clone(),
            decoy: None,
            options: EncodeOptions {
                population_decoys: decoys,
                decoy: DecoyKind::Noise,
                decoy_weight: weight,
                seed: self.seed.wrapping_mul(1000).wrapping_add(e as u64),
                sub_rays: self.setup.sub_rays,
                max_iterations: self.setup.max_iterations,
                evaluation_population: 0,
                ..Default::default()
            },
        };
        let enc = encode(&spec, &self.cache, &|_| {}, &self.cancel)
            .map_err(|err| anyhow::anyhow!("encoding view set {e}: {err}"))?;
        Ok(enc.light_field)
    }

    /// The viewers of view set `e`, labelled: its target, camera-like eyes (the first in focus, the others
    /// focused at random within ±1 D), then people from the pool.
    fn viewers(
        &self,
        e: usize,
        target: &VisionProfile,
        tag: &str,
        rng: &mut impl Rng,
    ) -> Result<Vec<(String, Observer)>> {
        let mut batch: Vec<(String, Observer)> = vec![(format!("target {tag}"), self.observer(target)?)];
        for c in 0..self.setup.cameras_per_encoding {
            let focus = if c == 0 { 0.0 } else { rng.gen_range(-1.0..=1.0) };
            let camera = VisionProfile {
                pupil_diameter_mm: 4.0,
                prescription: Some(Prescription {
                    sphere_d: focus,
                    cylinder_d: 0.0,
                    axis_deg: 0.0,
                }),
                ..VisionProfile::perfect()
            };
            batch.push((format!("camera focus={focus:+.2}D {tag}"), self.observer(&camera)?));
        }
        let per = self.setup.people_per_encoding;
        for i in 0..per {
            let p = &self.pool[(e * per + i) % self.pool.len()];
            batch.push((format!("person {tag}"), self.observer(p)?));
        }
        Ok(batch)
    }

    /// View set `e`: a random PIN encoded for a sampled target with the set's (decoys, weight), written as seen
    /// by each of its viewers until `count` views exist.
    fn view_set(&self, e: usize, out: &mut ViewWriter, count: usize, rng: &mut impl Rng) -> Result<()> {
        let d = &self.setup.display;
        let (decoys, weight) = self.combos[(e * self.stride) % self.combos.len()];
        let scale = self.scales[(e / self.combos.len() + e) % self.scales.len()];
        let pin = random_pin(rng);
        let doc = pin_document(&pin, d.holes_x, d.holes_y, scale);
        let scope = SamplingScope {
            pupil_spread: false,
            ..Default::default()
        };
        let target = sample_person(&mut *rng, scope);
        let t = Instant::now();
        let l = self.encode(e, &doc, &target, decoys, weight)?;
        let tag = format!("decoys={decoys} weight={weight} scale={scale}");
        let mut legs = Vec::new();
        for (kind, o) in self.viewers(e, &target, &tag, rng)? {
            if out.written >= count {
                break;
            }
            let (legibility, ncc, luminance) = score(&doc, &o, &l);
            legs.push(legibility);
            let text = pin.clone();
            out.push(View {
                text,
                legibility,
                ncc,
                kind,
                luminance,
            })?;
        }
        eprintln!(
            "view set {e}: {tag}: target {:.2}, others {} ({:.1} s; {} views, {:.0} s total)",
            legs.first().copied().unwrap_or(0.0),
            legs.iter()
                .skip(1)
                .map(|v| format!("{v:.2}"))
                .collect::<Vec<_>>()
                .join(" "),
            t.elapsed().as_secs_f64(),
            out.written,
            self.started.elapsed().as_secs_f64()
        );
        Ok(())
    }
}

/// Writes `count` views with `setup`: a quarter plain (when `count` ≥ 2), the rest of encodings, view set
/// after view set.
fn views_with(out_dir: &Path, count: usize, seed: u64, setup: &Setup) -> Result<()> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let views = Views::new(setup, seed, &mut rng);
    let mut out = ViewWriter::new(out_dir, setup.display.holes_x, setup.display.holes_y);
    let n_plain = if count >= 2 { count / 4 } else { 0 };
    for k in 0..n_plain {
        out.push(views.plain_view(k, &mut rng)?)?;
    }
    let mut e = 0usize;
    while out.written < count {
        views.view_set(e, &mut out, count, &mut rng)?;
        e += 1;
    }
    out.finish()
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_views_and_a_parseable_table() {
        let dir = tempfile::tempdir().unwrap();
        let setup = Setup {
            display: DisplayGeometry {
                aperture: Default::default(),
                holes_x: 24,
                holes_y: 24,
                views_u: 3,
                views_v: 3,
                ..DisplayGeometry::paper()
            },
            sub_rays: 2,
            view_sub_rays: 2,
            max_iterations: 5,
            decoys: vec![0, 2],
            weights: vec![0.3],
            people_per_encoding: 2,
            cameras_per_encoding: 1,
            pool: 2,
        };
        views_with(dir.path(), 6, 1, &setup).unwrap();
        let csv = std::fs::read_to_string(dir.path().join("views.csv")).unwrap();
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some("file,text,legibility,ncc,kind"));
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), 6);
        let mut kinds = std::collections::BTreeSet::new();
        for r in &rows {
            assert_eq!(r.len(), 5, "{r:?}");
            assert!(r[1].len() == 4 && r[1].chars().all(|c| c.is_ascii_digit()), "{r:?}");
            let leg: f64 = r[2].parse().unwrap();
            let ncc: f64 = r[3].parse().unwrap();
            assert!((0.0..=1.0).contains(&leg) && leg + 1e-9 >= ncc.abs(), "{r:?}");
            kinds.insert(r[4].split(' ').next().unwrap().to_string());
            let img = image::open(dir.path().join(r[0])).unwrap().to_luma8();
            assert_eq!(img.dimensions(), (24 * UPSCALE, 24 * UPSCALE));
        }
        assert!(kinds.contains("plain") && kinds.contains("target"), "{kinds:?}");
        // A sharp plain view of the document is legible.
        let doc = pin_document("4821", 24, 24, 1);
        let lum = eyekey_core::evaluation::image_luminance(&doc);
        assert!(eyekey_core::evaluation::legibility(&lum, &lum, 24, 24) > 0.99);
    }
}
