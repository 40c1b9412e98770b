//! The contact sheet: labelled views side by side and the population's legibility plot.

use crate::evaluation::Report;
use image::{Rgb, RgbImage};

/// One PNG with labelled tiles (objective, target, observers, worst person, camera's best) and a bar plot of
/// the population's legibility against the threshold.
pub fn contact_sheet(report: &Report, pictures: &[(String, RgbImage)]) -> RgbImage {
    let wanted = [
        "objective.png",
        "target.png",
        "observer_0.png",
        "population_worst.png",
        "camera_best.png",
    ];
    let tiles: Vec<(&str, &RgbImage)> = wanted
        .iter()
        .filter_map(|w| pictures.iter().find(|(n, _)| n == w).map(|(n, p)| (n.as_str(), p)))
        .collect();
    let tile = 160u32;
    let label_h = 24u32;
    let cols = tiles.len() as u32 + 1;
    let mut sheet = RgbImage::from_pixel(cols * (tile + 8) + 8, tile + label_h + 16, Rgb([255, 255, 255]));
    let score_of = |name: &str| -> Option<f64> {
        match name {
            "target.png" => Some(report.target.legibility),
            "observer_0.png" => report.observers.first().map(|s| s.legibility),
            "population_worst.png" => report.population.as_ref().map(|p| p.max_legibility),
            "camera_best.png" => report.camera.as_ref().map(|c| c.best.legibility),
            _ => None,
        }
    };
    for (k, (name, pic)) in tiles.iter().enumerate() {
        let x0 = 8 + k as u32 * (tile + 8);
        let scaled = image::imageops::resize(*pic, tile, tile, image::imageops::FilterType::Nearest);
        image::imageops::replace(&mut sheet, &scaled, x0 as i64, 8);
        let short = match *name {
            "population_worst.png" => "WORST".to_string(),
            other => other.trim_end_matches(".png").replace('_', " ").to_uppercase(),
        };
        let text = match score_of(name) {
            Some(s) => format!("{} {:.2}", short.split(' ').next().unwrap_or(""), s),
            None => short.split(' ').next().unwrap_or("").to_string(),
        };
        let label = crate::imaging::glyphs::render_text(&[&text], tile, label_h, 2);
        image::imageops::replace(&mut sheet, &label, x0 as i64, (tile + 12) as i64);
    }
    // Plot: one bar per sampled person (legibility), a red line at the threshold, the target in green.
    let x0 = 8 + tiles.len() as u32 * (tile + 8);
    let mut legs: Vec<f64> = report
        .population
        .as_ref()
        .map(|p| p.people.iter().map(|s| s.legibility).collect())
        .unwrap_or_default();
    legs.sort_by(|a, b| a.total_cmp(b));
    // One column per pixel: the sorted legibilities resampled to the plot's width (a quantile plot), so a
    // population of any size fills it.
    let y_of = |v: f64| 8 + tile - ((v.clamp(0.0, 1.0) * tile as f64) as u32).min(tile);
    if !legs.is_empty() {
        for x in 0..tile {
            let v = legs[(x as usize * legs.len() / tile as usize).min(legs.len() - 1)];
            for y in y_of(v)..8 + tile {
                sheet.put_pixel(x0 + x, y, Rgb([90, 90, 200]));
            }
        }
    }
    for x in x0..x0 + tile {
        sheet.put_pixel(x, y_of(report.threshold).min(7 + tile), Rgb([220, 0, 0]));
        sheet.put_pixel(x, y_of(report.target.legibility).min(7 + tile), Rgb([0, 170, 0]));
    }
    let label = crate::imaging::glyphs::render_text(&["PEOPLE"], tile, label_h, 2);
    image::imageops::replace(&mut sheet, &label, x0 as i64, (tile + 12) as i64);
    sheet
}
