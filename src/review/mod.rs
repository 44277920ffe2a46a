//! What the studio asks of a session's results, answered by the core so that the app
//! only shows: measured sweep points and the model and truth curves beside them (the
//! paper's Fig. 4), predicted and true Gaussian fields, the numbers behind one square,
//! the kernels a photo is deblurred with, and deblurred crops of a photo region side by
//! side (the paper's Fig. 7–8 comparison of predicted Gaussians and measured kernels).
//!
//! This module is core: it never touches egui. Its parts, each re-exported here:
//! - [`sweeps`]: settings along a sweep, measured sweep points, model and truth curves;
//! - [`fields`]: predicted and true Gaussian fields on a grid, field differences,
//!   colour ranges;
//! - [`kernels`]: predicted kernels at points and their error against measured ones,
//!   the noisy-kernel criterion, the facts of one aligned square;
//! - [`crops`]: a photo region deblurred with a profile and with measured kernels;
//! - [`export`]: a deblurred photo written whole, plot data as CSV, PNG cuts;
//! - [`plot`]: cross-validation curves and tick placement;
//! - [`sharpness`]: the sharpness map (MTF50 over the frame), its CSV and picture;
//! - [`advice`]: shooting advice;
//! - [`coverage`]: where on the sensor the chart has been, per setting, and the parts
//!   of the frame still to cover;
//! - [`lens_geometry`]: a measured geometry as the Geometry view draws it (the grid
//!   through the distortion, lateral-colour arrows, the fall-off map);
//! - [`overlay`]: a detection as the Shot view draws it (the chart's grid, a square's
//!   circles, the square under a point).

pub mod advice;
pub mod coverage;
pub mod crops;
pub mod export;
pub mod fields;
pub mod kernels;
pub mod lens_geometry;
pub mod overlay;
pub mod plot;
pub mod sharpness;
pub mod sweeps;

pub use advice::{
    AdviceLevel, LensRange, PlanGrid, PlanProgress, PlannedSetting, SHOTS_PER_SETTING,
    ShootingAdvice, plan_grid, plan_progress, shooting_advice, shooting_plan,
};
pub use coverage::{
    COVERAGE_CELLS, COVERAGE_PARTS, PART_COVERED, SettingCoverage, coverage, coverage_of_dataset,
    coverage_of_points,
};
pub use crops::{
    DeblurComparison, Region, compare_deblur, crop_capture, deblur_region, display_whites,
    measured_at, measured_source, profile_source, region_planes,
};
pub use export::{PlotTable, plot_csv, write_png_crop};
pub use fields::{
    FieldDifference, colour_range, ellipse_outline, field_difference, field_grid, palette_rgb,
    predicted_at, predicted_field, truth_field, truth_pixel_gaussian,
};
pub use kernels::{
    KernelError, KernelTails, NOISY_TAIL_FRACTION, PredictedKernel, SquareFacts, kernel_errors,
    kernel_tail_fraction, kernel_tails, no_shape_reason, noisy_kernel_reason, predicted_kernels,
    skip_reasons, square_facts,
};
pub use lens_geometry::{
    ColourArrows, FalloffMap, WarpedGrid, colour_arrows, falloff_map, nice_factor, stops_at,
    warped_grid,
};
pub use overlay::{chart_grid, point_in_quad, square_circles};
pub use plot::{
    CvCurveAxis, aperture_stops, cv_cdf_axis_end, cv_cdf_curves, cv_curve, cv_curve_axis,
    f_number_at_stops, f_number_label, nice_ticks,
};
pub use sharpness::{MapSummary, Mtf50Direction, SharpnessMap, SharpnessUnit, map_grid};
pub use sweeps::{
    SWEEP_REACH_SQUARES, SweepPoint, model_curve, nearest_value, sweep_points, sweep_settings,
    truth_curve,
};

#[cfg(test)]
mod tests;
