//! eyekey: show a document on a 5D light-field display so that only one enrolled person can read it.
//!
//! This crate holds the applications built on [`eyekey_core`] (the physics, encoders, evaluation and bundle
//! format): the product command line ([`cli`]), the display client ([`client`]), the REST service ([`service`])
//! and the research commands that reproduce the documented figures ([`research`]). Cargo enforces the layering:
//! the core cannot depend on anything here.

pub mod cli;
pub mod client;
pub mod research;
pub mod service;
