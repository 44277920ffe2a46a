//! One file per subcommand: its arguments and a `run` that calls into the core.

pub mod calibrate;
pub mod chart;
pub mod common;
pub mod crossval;
pub mod deblur;
pub mod deblur_batch;
pub mod detect;
pub mod experiment;
pub mod info;
pub mod kernels;
pub mod lensfun;
pub mod predict;
pub mod sharpness;
pub mod simulate;
pub mod studio;
pub mod sweeps;
