//! Writes `examples/documents/photo.png`: a synthetic landscape (sky, sun, three mountain ranges, a lake with
//! their reflection), made procedurally so that the repository holds no third-party photograph.
//!
//! ```sh
//! cargo run --release --example make_photo -- examples/documents/photo.png
//! ```
//!
//! Deterministic: the same file every time.

use image::{Rgb, RgbImage};

const WIDTH: u32 = 240;
const HEIGHT: u32 = 180;

/// A hash of an integer lattice point to [0, 1).
fn lattice(x: i64, seed: u64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed.wrapping_mul(0xD1B5_4A32_D192_ED03);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth 1-D value noise in [0, 1).
fn noise1(x: f64, seed: u64) -> f64 {
    let i = x.floor();
    let t = x - i;
    let s = t * t * (3.0 - 2.0 * t);
    let (a, b) = (lattice(i as i64, seed), lattice(i as i64 + 1, seed));
    a + (b - a) * s
}

/// Fractal (fBm) value noise: a ridge line with detail at every scale.
fn ridge(x: f64, seed: u64) -> f64 {
    (0..6)
        .map(|octave| {
            let f = (1u32 << octave) as f64;
            noise1(x * f, seed + octave as u64) / f
        })
        .sum::<f64>()
        / 1.97
}

/// A small per-pixel texture in [-1, 1].
fn grain(x: u32, y: u32, seed: u64) -> f64 {
    lattice((x as i64) * 7919 + (y as i64) * 104_729, seed) * 2.0 - 1.0
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t.clamp(0.0, 1.0))
}

/// The scene above the water line at (x, y), both in [0, 1] (y down).
fn scene(x: f64, y: f64, px: u32, py: u32) -> [f64; 3] {
    let horizon = 0.62;
    // Sky: deep blue at the top to a pale haze at the horizon, with a warm sun glow.
    let mut c = mix([0.22, 0.42, 0.78], [0.86, 0.84, 0.80], (y / horizon).powf(1.6));
    let (sx, sy) = (0.72, 0.22);
    let d = ((x - sx).powi(2) + (y - sy).powi(2) * 1.3).sqrt();
    c = mix(c, [1.0, 0.92, 0.70], (0.35 - d).max(0.0) * 2.0);
    if d < 0.05 {
        c = [1.0, 0.97, 0.88];
    }
    // Three ranges, far to near: lower, darker, greener and more textured as they come closer.
    let ranges = [
        (0.44, 0.34, 2.0, 11, [0.55, 0.60, 0.72]),
        (0.52, 0.26, 3.5, 23, [0.33, 0.42, 0.44]),
        (0.58, 0.14, 7.0, 37, [0.18, 0.30, 0.17]),
    ];
    for (k, (base, height, freq, seed, colour)) in ranges.into_iter().enumerate() {
        let top = base - height * ridge(x * freq, seed);
        if y >= top {
            let depth = ((y - top) / (horizon - top).max(1e-3)).clamp(0.0, 1.0);
            let shade = 1.0 - 0.35 * depth + 0.04 * (k as f64 + 1.0) * grain(px, py, seed);
            c = colour.map(|v| v * shade);
        }
    }
    c
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "examples/documents/photo.png".to_string());
    let horizon = 0.62;
    let img = RgbImage::from_fn(WIDTH, HEIGHT, |px, py| {
        let x = px as f64 / (WIDTH - 1) as f64;
        let y = py as f64 / (HEIGHT - 1) as f64;
        let c = if y < horizon {
            scene(x, y, px, py)
        } else {
            // The lake mirrors the scene, darker and rippled, with a sandy shore at the bottom.
            let mirrored = 2.0 * horizon - y;
            let ripple = 0.006 * (y * 180.0 + 3.0 * noise1(x * 20.0 + y * 50.0, 5)).sin();
            let reflected = scene((x + ripple).clamp(0.0, 1.0), mirrored.max(0.0), px, py);
            let water = mix(reflected.map(|v| v * 0.75), [0.10, 0.22, 0.32], (y - horizon) * 1.6);
            let shore = 0.93 - 0.03 * ridge(x * 6.0, 61);
            if y > shore {
                [0.76, 0.68, 0.52].map(|v| v * (1.0 + 0.06 * grain(px, py, 71)))
            } else {
                water
            }
        };
        Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
    });
    img.save(&out)?;
    println!("wrote {out} ({WIDTH}×{HEIGHT})");
    Ok(())
}
