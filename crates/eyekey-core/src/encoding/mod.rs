//! Encoders (docs/design.md §3): the objectives of paper Eqs. 14 and 16, the box-constrained solver, and the
//! pipeline that turns a job into a frame bundle.

pub mod footprint;
pub mod job;
pub mod leak;
pub mod objectives;
pub mod options;
pub mod pipeline;
pub mod solver;
