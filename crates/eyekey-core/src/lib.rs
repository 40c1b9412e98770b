//! eyekey-core: the physics, encoders, evaluation and frame-bundle format of eyekey, which shows a document on a
//! 5D light-field display so that only one enrolled person can read it.
//!
//! The layers, each using only those before it:
//! - [`physics`]: vision profiles (Zernike wavefronts, cone fundamentals), the display, light transport, the
//!   observer model and population statistics;
//! - [`imaging`]: documents in and pictures out (sRGB ⇄ LMS, PNG, glyphs);
//! - [`encoding`]: the box-constrained solver, the encoders' objectives and the offline pipeline;
//! - [`evaluation`]: who can read a result (metrics, attackers, report, contact sheet);
//! - [`bundle`]: the frame-bundle format a display shows.
//!
//! The crate is synchronous and knows nothing of the service: no async runtime, HTTP or database. The design it
//! implements is `docs/design.md` in the repository.

pub mod bundle;
pub mod encoding;
pub mod evaluation;
pub mod imaging;
pub mod physics;
