//! Research commands: benchmarks, experiments and the legibility calibration that produce the figures in
//! BENCHMARKS.md, docs/experiments.md and docs/legibility-calibration.md.

pub mod bench;
pub mod calibration;
pub mod experiment;
