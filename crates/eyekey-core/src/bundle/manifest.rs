//! The manifest: what a bundle holds and how it was made.

use crate::physics::display::DisplayGeometry;
use serde::{Deserialize, Serialize};

/// The contents of `manifest.json`: everything needed to show and to audit a bundle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Layout version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// When the bundle was written, RFC 3339 in UTC.
    pub created_at: String,
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
    /// Identifier and version of the target's profile; never the profile's contents.
    pub profile_label: String,
    /// The encoder: method and its parameters.
    pub encoder: serde_json::Value,
    /// Solver statistics: iterations, termination, final objective, time, ...
    pub solver: serde_json::Value,
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

/// What the caller records about an encode in the manifest.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BundleMeta {
    /// Identifier and version of the target's profile; never the profile's contents.
    pub profile_label: String,
    /// The encoder: method and its parameters (the serialised `EncodeOptions`).
    pub encoder: serde_json::Value,
    /// Solver statistics: iterations, termination, final objective, time, ...
    pub solver: serde_json::Value,
}
