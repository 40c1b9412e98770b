//! Research commands: benchmarks, experiments and the legibility calibration that produce the figures in
//! BENCHMARKS.md, docs/experiments.md, docs/legibility-calibration.md and docs/legibility-ocr.md.

pub mod bench;
pub mod bystanders;
pub mod calibration;
pub mod defaults;
pub mod encoders;
pub mod experiment;
pub mod scale;
pub mod wave;

/// A view's known-font reading for a table cell: `"4021" (3/4)`, or – when it was not read.
pub(crate) fn known_font_cell(score: &eyekey_core::evaluation::ViewScore) -> String {
    score
        .known_font
        .as_ref()
        .map(|k| format!("\"{}\" ({}/{})", k.text, k.characters_right, k.characters))
        .unwrap_or_else(|| "–".into())
}

/// The head of a Markdown table: the column names and the `| --- |` rule, each line ending in a newline.
pub(crate) fn table_header(columns: &[&str]) -> String {
    let rule = vec!["---"; columns.len()];
    format!("| {} |\n| {} |\n", columns.join(" | "), rule.join(" | "))
}
