//! The manifest: what a bundle holds, and nothing else.

use crate::physics::display::DisplayGeometry;
use serde::{Deserialize, Serialize};

/// The contents of `manifest.json`: what a display needs to show the frames and to check it has them whole, and
/// nothing more. Each field and why the display needs it:
///
/// | field | why |
/// | --- | --- |
/// | `format_version` | to refuse a layout it does not know |
/// | `display` | the geometry and projector spectra the frames are laid out for, checked against the display's own |
/// | `frame_width`, `frame_height`, `n_frames` | the size and number of the frames, checked before they are decoded |
/// | `barrier_mask_pixels_per_hole` | how to scale the barrier mask onto the barrier |
/// | `files` | name, size, SHA-256 and role of every other file, so a damaged or missing file is refused |
///
/// Never the encoder's options or seed, the solver's record, the target's profile or its label, a time, or
/// anything of the document: those stay with the operator (`encoding.json`, `report.json`), sealed in the
/// service. Unknown fields are refused, so a manifest that carries more is not a bundle of this format.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Layout version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// The display the frames are for, including its projector spectra and L_max.
    pub display: DisplayGeometry,
    /// Width of every frame, pixels (X·U).
    pub frame_width: u32,
    /// Height of every frame, pixels (Y·V).
    pub frame_height: u32,
    /// Number of frames, one per projector band.
    pub n_frames: u32,
    /// Resolution of the barrier-mask PNG, pixels per hole pitch.
    pub barrier_mask_pixels_per_hole: u32,
    /// Every file of the bundle except the manifest itself.
    pub files: Vec<FileEntry>,
}

/// One file of a bundle as listed in the manifest.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// Plain file name within the bundle (no directories).
    pub name: String,
    /// Lower-case hex SHA-256 of the file's bytes.
    pub sha256: String,
    /// Size of the file, bytes.
    pub bytes: u64,
    /// What the file is.
    pub role: FileRole,
}

/// What a bundle file is. In JSON the variant is a `kind` tag: `{"kind": "frame", "band": 0}`,
/// `{"kind": "barrier_mask"}`, `{"kind": "other"}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FileRole {
    /// The frame of one projector band.
    Frame {
        /// The band (projector) index n.
        band: u32,
    },
    /// The barrier-mask PNG.
    BarrierMask,
    /// Anything else (a report, say): checksummed, otherwise not interpreted.
    Other,
}
