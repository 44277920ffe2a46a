//! The simulator: a virtual lens and a capture model that feed the tests, benchmarks
//! and the studio's demo session with exact ground truth.

pub mod aberration;
pub mod capture;
pub mod demo;
pub mod distortion;
pub mod files;
pub mod lens;
pub mod scene;
pub mod session;

pub use crate::dng::{DngCompression, DngLayout};
pub use capture::{
    CaptureParams, NoiseModel, Pose, PsfField, ShotTruth, SimulateError, SimulatedShot,
    SquareTruth, capture_from_raw, simulate_shot,
};
pub use distortion::{LensGeometry, SensorMapping};
pub use files::{ShotFormat, write_shot, write_shot_as};
pub use lens::{Aberrations, PsfShape, Seidel, VirtualLens, flat_field};
pub use scene::{blur_varying, camera_like_mosaic, dead_leaves, hard_edges};
pub use session::{SampleNoise, SimulatedSession};
