//! Research commands: benchmarks, experiments and the legibility calibration that produce the figures in
//! BENCHMARKS.md, docs/experiments.md, docs/legibility-calibration.md and docs/legibility-ocr.md.

pub mod bench;
pub mod bystanders;
pub mod calibration;
pub mod defaults;
pub mod encoders;
pub mod experiment;
pub mod wave;

/// The head of a Markdown table: the column names and the `| --- |` rule, each line ending in a newline.
pub(crate) fn table_header(columns: &[&str]) -> String {
    let rule = vec!["---"; columns.len()];
    format!("| {} |\n| {} |\n", columns.join(" | "), rule.join(" | "))
}
