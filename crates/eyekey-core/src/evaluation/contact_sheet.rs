//! The contact sheet: labelled views side by side and the population's legibility plot.

use crate::evaluation::Report;
use image::{Rgb, RgbImage};

/// One PNG with labelled tiles (objective, target, observers, worst person, camera's best) and, when people
/// were sampled, a plot of the population's legibility against the threshold.
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
    // The people's legibilities, sorted; no plot without them (an evaluation of bystanders or cameras alone).
    let mut legs: Vec<f64> = report
        .population
        .as_ref()
        .map(|p| p.people.iter().map(|s| s.legibility).collect())
        .unwrap_or_default();
    legs.sort_by(|a, b| a.total_cmp(b));
    let cols = tiles.len() as u32 + u32::from(!legs.is_empty());
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
    if legs.is_empty() {
        return sheet;
    }
    // Plot: one bar per sampled person (legibility), a red line at the threshold, the target in green.
    let x0 = 8 + tiles.len() as u32 * (tile + 8);
    // One column per pixel: the sorted legibilities resampled to the plot's width (a quantile plot), so a
    // population of any size fills it.
    let y_of = |v: f64| 8 + tile - ((v.clamp(0.0, 1.0) * tile as f64) as u32).min(tile);
    for x in 0..tile {
        let v = legs[(x as usize * legs.len() / tile as usize).min(legs.len() - 1)];
        for y in y_of(v)..8 + tile {
            sheet.put_pixel(x0 + x, y, Rgb([90, 90, 200]));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::report::{PopulationSummary, ViewScore};

    fn score(label: &str, legibility: f64) -> ViewScore {
        ViewScore {
            label: label.into(),
            legibility,
            ncc: 0.0,
            psnr_db: 0.0,
            focus_d: None,
            learned: None,
            ssim: 0.0,
            known_font: None,
            readable: legibility >= 0.5,
        }
    }

    /// The people's plot is drawn when people were sampled, its bars as tall as their legibilities, and left
    /// out (not drawn empty) when none were.
    #[test]
    fn the_people_plot_appears_only_with_people() {
        let mut report = Report {
            metric: "test".into(),
            threshold: 0.5,
            target: score("target", 0.9),
            target_reading: crate::evaluation::TargetReading {
                judge: crate::evaluation::TargetJudge::Legibility,
                reads: true,
                score: 0.9,
                bar: crate::evaluation::READS_THRESHOLD,
            },
            observers: vec![],
            population: None,
            camera: None,
            key_sensitivity: None,
            head_movement: None,
            bystanders: None,
            learned_reader: None,
        };
        let pictures = vec![("target.png".to_string(), RgbImage::from_pixel(8, 8, Rgb([0, 0, 0])))];
        let without = contact_sheet(&report, &pictures);
        assert_eq!(without.width(), 8 + 168, "one tile and no plot");
        report.population = Some(PopulationSummary::from_scores(
            (0..10).map(|i| score("person", i as f64 / 20.0)).collect(),
        ));
        let with = contact_sheet(&report, &pictures);
        assert_eq!(with.width(), 8 + 2 * 168, "one tile and the plot");
        // The plot's last column is the most legible person (0.45 of the 160-pixel plot): 72 pixels of bar.
        let bar = |x: u32| {
            (8..168)
                .filter(|y| *with.get_pixel(x, *y) == Rgb([90, 90, 200]))
                .count()
        };
        assert_eq!(bar(176 + 159), 72);
        assert_eq!(bar(176), 0, "the least legible person reads 0");
    }
}
