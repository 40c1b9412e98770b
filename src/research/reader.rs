//! `eyekey experiment reader-views`: the views a learned reader trains and is tested on (docs/experiments.md §0b).
//!
//! An attacker who knows eyekey (its code, defaults, the display, the PIN slip's font and layout, the population's
//! statistics) encodes PIN slips for sampled targets, simulates what people see of the frames, and trains a
//! reader on the character cells. This command makes those encodings, each with its own fresh seed (as every job
//! draws one), its own target and PIN, and writes every view's secret character cells, the truth and what the
//! matched filter (the known-font attacker) read from the same view. `benches/learned_reader/train.py` trains
//! and tests the readers on them.
//!
//! Each encoding's views, by condition:
//! - `seat`: fresh people from the population at the target's position, at their own focus;
//! - `seat_refocused`: the same people accommodated to the target's spherical equivalent within −1 to +2 D
//!   ([`Accommodation::matching`]), the focus a reader would look for first;
//! - `beside`: the same people 10 mm to the right of the target's pupil, unwarped back onto the document's
//!   layout (the attacker knows where they stand, [`unwarp`]);
//! - `camera_band_k`: an ideal 4 mm camera lens at the seat, focused on the display, behind a filter passing
//!   projector band k;
//! - `target`: the target's own view under a kernel draw the encoder did not use.
//!
//! Output: `views.f32` (every record's cells, little-endian f32, each cell row-major, the cells in text order,
//! the luminance divided by the viewer's white) and `views.json` (the grid, the cells' boxes, one entry per record).

use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Result;
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::experiment::pin_slip_of;
use eyekey_core::encoding::pipeline::{encode, EncodeOptions, JobSpec, PipelineError};
use eyekey_core::evaluation::{luminance, luminance_of, unwarp, KnownFontAttacker};
use eyekey_core::physics::accommodation::Accommodation;
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{transports, Lens, Observer};
use eyekey_core::physics::population::sample_population;
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportCache, TransportOptions};
use eyekey_core::physics::zernike::{Prescription, ZernikeCoefficients};

/// What to make.
pub struct Setup {
    /// Display preset.
    pub preset: String,
    /// Encodings (each its own target, PIN and seed).
    pub encodings: u32,
    /// People per encoding.
    pub people: u32,
    /// The first encoding's index: runs with different starts make disjoint encodings.
    pub first: u32,
}

/// One view's record in `views.json`.
#[derive(Serialize)]
struct Record {
    encoding: u32,
    condition: String,
    /// The PIN.
    truth: String,
    /// What the matched filter read from the same view, and whether every digit is right.
    matched_filter: String,
    matched_filter_correct: bool,
}

#[derive(Serialize)]
struct Manifest {
    preset: String,
    grid: [u32; 2],
    /// Each secret cell's box on the grid: x0, y0, width, height.
    cells: Vec<[usize; 4]>,
    /// Floats per record.
    features: usize,
    options: String,
    records: Vec<Record>,
    encodings_refused: u32,
    seconds: f64,
}

/// A camera's ideal lens of `aperture_mm` focused on the display behind a filter passing band `band` alone.
fn camera_band(
    display: &DisplayGeometry,
    band: usize,
    topts: &TransportOptions,
    options: &EncodeOptions,
    cache: &TransportCache,
) -> Result<Observer> {
    let rx = Prescription {
        sphere_d: 0.0,
        cylinder_d: 0.0,
        axis_deg: 0.0,
    };
    let lens = ZernikeCoefficients::from_prescription(&rx, 4.0);
    let tr = transports(
        display,
        Lens::Achromat(&lens),
        EyePosition::default(),
        topts,
        options.optics,
        cache,
    )?;
    let coupling = (0..display.n_bands())
        .map(|m| if m == band { [1.0; 3] } else { [0.0; 3] })
        .collect();
    Ok(Observer::with_coupling(tr, coupling, display.l_max))
}

/// Makes the views; returns a one-line summary.
pub fn run(out: &Path, setup: &Setup, options: EncodeOptions) -> Result<String> {
    options.validate().map_err(|e| anyhow::anyhow!("encode options: {e}"))?;
    std::fs::create_dir_all(out)?;
    let display = DisplayGeometry::preset(&setup.preset)?;
    let cache = TransportCache::default();
    let topts = TransportOptions {
        sub_rays: options.sub_rays,
        seed: 0x005E_ED0F_EA5E,
        ..Default::default()
    };
    let started = Instant::now();
    let grid = Observer::new(
        &display,
        &VisionProfile::perfect(),
        EyePosition::default(),
        &topts,
        options.optics,
        &cache,
    )?
    .grid();
    let (width, height) = (display.holes_x * 4, display.holes_y * 4);
    let cameras: Vec<Observer> = (0..display.n_bands())
        .map(|b| camera_band(&display, b, &topts, &options, &cache))
        .collect::<Result<_>>()?;
    let mut floats = std::io::BufWriter::new(std::fs::File::create(out.join("views.f32"))?);
    let mut manifest = Manifest {
        preset: setup.preset.clone(),
        grid: [grid.width, grid.height],
        cells: Vec::new(),
        features: 0,
        options: format!(
            "security {:?}, decoys' focus {:?}",
            options.security, options.decoy_focus
        ),
        records: Vec::new(),
        encodings_refused: 0,
        seconds: 0.0,
    };
    let range = Accommodation::default();
    for i in setup.first..setup.first + setup.encodings {
        // Each encoding's own stream: its target, PIN, encoder seed and people, apart from every other's and from
        // the evaluation's and the experiments' seeds.
        let stream = 0x001E_A4ED_0000_u64 + u64::from(i) * 7_919;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(stream);
        let target = sample_population(1, stream ^ 0x7A5, Default::default()).remove(0);
        let pin: String = (0..4).map(|_| char::from(b'0' + rng.gen_range(0..10u8))).collect();
        let (document, text) = pin_slip_of(width, height, &pin);
        let attacker = KnownFontAttacker::new(&text, width, height, grid.width, grid.height)?;
        let boxes: Vec<[usize; 4]> = attacker
            .discriminants()
            .into_iter()
            .map(|((x0, y0, w, h), _)| [x0, y0, w, h])
            .collect();
        if manifest.cells.is_empty() {
            manifest.features = boxes.iter().map(|b| b[2] * b[3]).sum();
            manifest.cells = boxes.clone();
        }
        anyhow::ensure!(boxes == manifest.cells, "every PIN slip has the same cells");
        let spec = JobSpec {
            display: display.clone(),
            target: target.clone(),
            target_label: format!("encoding {i}"),
            observers: vec![],
            document,
            decoy: None,
            options: EncodeOptions {
                document_text: Some(text),
                seed: Some(stream ^ rng.gen::<u64>()),
                ..options.clone()
            },
        };
        let enc = match encode(&spec, &cache, &|_| {}, &AtomicBool::new(false)) {
            Ok(enc) => enc,
            Err(PipelineError::TargetCannotRead { .. }) => {
                manifest.encodings_refused += 1;
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let l = &enc.light_field;
        let mut write = |condition: &str, lum: &[f32], white: f64| -> Result<()> {
            let read = attacker.read(lum);
            for &[x0, y0, w, h] in &boxes {
                for y in y0..y0 + h {
                    for x in x0..x0 + w {
                        floats.write_all(&((lum[y * grid.width as usize + x] as f64 / white) as f32).to_le_bytes())?;
                    }
                }
            }
            manifest.records.push(Record {
                encoding: i,
                condition: condition.to_string(),
                truth: pin.clone(),
                matched_filter: read.text,
                matched_filter_correct: read.correct,
            });
            Ok(())
        };
        let seen = |o: &Observer| (luminance(&o.view(l)), luminance_of(o.white));
        let at = |p: &VisionProfile, eye: EyePosition| Observer::new(&display, p, eye, &topts, options.optics, &cache);
        let people = sample_population(setup.people as usize, stream ^ 0xB1D, Default::default());
        let beside = EyePosition {
            x_mm: 10.0,
            y_mm: 0.0,
            dz_mm: 0.0,
        };
        for person in &people {
            let (lum, white) = seen(&at(person, EyePosition::default())?);
            write("seat", &lum, white)?;
            let (refocused, _) = range.matching(person, &target)?;
            let (lum, white) = seen(&at(&refocused, EyePosition::default())?);
            write("seat_refocused", &lum, white)?;
            let o = at(person, beside)?;
            let (lum, white) = seen(&o);
            write("beside", &unwarp(&lum, &o.grid(), &display, beside), white)?;
        }
        for (b, cam) in cameras.iter().enumerate() {
            let lum: Vec<f32> = cam.view(l).chunks_exact(3).map(|p| p[0]).collect();
            write(&format!("camera_band_{b}"), &lum, cam.white[0])?;
        }
        let (lum, white) = seen(&at(&target, EyePosition::default())?);
        write("target", &lum, white)?;
        eprintln!(
            "encoding {i}: PIN {pin}, {} records, {:.0} s",
            manifest.records.len(),
            started.elapsed().as_secs_f64()
        );
    }
    floats.flush()?;
    manifest.seconds = started.elapsed().as_secs_f64();
    std::fs::write(out.join("views.json"), serde_json::to_vec(&manifest)?)?;
    Ok(format!(
        "{} records of {} encodings ({} refused) on `{}`, {} floats each, in {:.0} s: {}",
        manifest.records.len(),
        setup.encodings - manifest.encodings_refused,
        manifest.encodings_refused,
        setup.preset,
        manifest.features,
        manifest.seconds,
        out.display()
    ))
}
