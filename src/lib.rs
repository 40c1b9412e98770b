//! eyekey: show a document on a 5D light-field display so that only one enrolled person can read it.
//!
//! The physics and solvers (`optics`, `spectral`, `display`, `transport`, `solve`, `encode`, `evaluate`)
//! are synchronous and know nothing of the service; `service` depends on them, never the reverse.

pub mod bench;
pub mod bundle;
pub mod calibration;
pub mod cli;
pub mod client;
pub mod display;
pub mod encode;
pub mod evaluate;
pub mod experiment;
pub mod glyphs;
pub mod imaging;
pub mod observer;
pub mod optics;
pub mod pipeline;
pub mod population;
pub mod service;
pub mod solve;
pub mod spectral;
pub mod transport;
