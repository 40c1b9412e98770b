//! Ocular optics: Zernike wavefronts (OSA/ANSI Z80.28) and vision profiles.

pub mod profile;
pub mod zernike;
