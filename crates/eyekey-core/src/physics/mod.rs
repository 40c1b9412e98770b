//! The physical model: the viewer's eye, the display and the light transport between them (docs/design.md §2).

pub mod accommodation;
pub mod chromatic;
pub mod diffraction;
pub mod display;
pub mod fourier;
pub mod mtf;
pub mod observer;
pub mod population;
pub mod profile;
pub mod resolvability;
pub mod spectral;
pub mod tracking;
pub mod transport;
pub mod zernike;
