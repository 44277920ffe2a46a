//! lensblur: measure, model and remove a lens's own spatially varying optical blur,
//! after Kee, Paris, Chen and Wang, "Modeling and Removing Spatially-Varying Optical
//! Blur" (ICCP 2011).
//!
//! The core is one module per pipeline stage and never depends on egui; the studio lives
//! in `app` behind the `gui` feature.

#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

#[cfg(feature = "gui")]
pub mod app;
pub mod batch;
pub mod calibrate;
pub mod chart;
pub mod correction;
pub mod crossval;
pub mod deblur;
pub mod detect;
pub mod develop;
pub mod dng;
pub mod experiment;
pub mod fft;
pub mod format;
pub mod fuzz;
pub mod gaussian;
pub mod geometry;
pub mod io;
pub mod job;
pub mod kernel;
#[cfg(test)]
mod layers;
pub mod limits;
pub mod lock;
pub mod manifest;
pub mod metrics;
pub mod model;
pub mod pipeline;
pub mod plane;
pub mod profile;
pub mod project;
pub mod psf;
pub mod raw;
pub mod recent;
pub mod review;
pub mod session;
pub mod shot_file;
pub mod simulate;
pub mod timings;
