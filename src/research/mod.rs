//! Research commands: benchmarks, experiments and the legibility calibration that produce the figures in
//! BENCHMARKS.md, docs/experiments.md, docs/legibility-calibration.md and docs/legibility-ocr.md.

pub mod bench;
pub mod bystanders;
pub mod calibration;
pub mod defaults;
pub mod encoders;
pub mod experiment;
pub mod fonts;
pub mod reader;
pub mod scale;
pub mod wave;

/// The encoder's seed in experiments and benchmarks that give none, so that their figures reproduce. A job never
/// runs with it: without a seed of its own an encode draws a fresh one ([`EncodeOptions::seed`]), and a seed
/// anybody knows is a fixed noise pattern an attacker can learn.
///
/// [`EncodeOptions::seed`]: eyekey_core::encoding::pipeline::EncodeOptions::seed
pub const EXPERIMENT_SEED: u64 = 1;

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
