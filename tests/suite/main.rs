//! The integration tests, one binary: each module is what was a test file of its own.
//! Linked once instead of once per file, which a cold build (CI) pays for in minutes.
//! The studio's tests stay a binary of their own (`tests/studio.rs`): a process has one
//! GPU deblurrer, and the studio lends it the window's device.

mod assets;
mod batch;
mod crash_safety;
mod deblur;
mod detect;
mod developed;
mod formats;
mod fuzz_smoke;
mod kernels;
mod lensfun;
mod load;
mod model;
mod pipeline;
mod positions;
mod project;
mod raw_worker;
mod real_deblur;
mod real_files;
mod sessions;
mod simulate;

/// The global model of orders α, β calibrated on `ds`, given rather than chosen by
/// cross-validation: the profile the model, trust and deblurring tests start from.
pub(crate) fn global_profile(
    ds: &lensblur::model::Dataset,
    alpha: usize,
    beta: usize,
) -> lensblur::profile::Profile {
    let opts = lensblur::calibrate::CalibrateOptions {
        families: lensblur::calibrate::Families::Global,
        alpha: Some(alpha),
        beta: Some(beta),
        ..lensblur::calibrate::CalibrateOptions::default()
    };
    lensblur::calibrate::calibrate(ds, None, &opts, &lensblur::job::JobContext::silent())
        .expect("calibrate")
        .0
}
