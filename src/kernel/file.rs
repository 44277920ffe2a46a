//! The kernels file (`lensblur.kernels/1`, DESIGN.md §3): what `lensblur kernels`
//! writes, and what calibration and deblurring read. One type for both directions so
//! the writer and its readers cannot drift apart.

use super::ShotKernels;
use crate::plane::{CameraIdentity, Channel};
use crate::psf::Kernel;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The kernels file's version. Files from before the field was written have none and
/// are version 1.
pub const KERNELS: crate::format::Schema = crate::format::Schema {
    kind: "kernels",
    current: 1,
    unversioned: Some(1),
};

/// A kernel array as stored: odd `size`, `size²` values row-major at the file's
/// oversampling, summing to 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelData {
    pub size: usize,
    pub data: Vec<f64>,
}

/// A Gaussian as the file stores it: C_xx = σx, C_yy = σy (px), C_or = ρ.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GaussianRecord {
    pub cxx: f64,
    pub cyy: f64,
    pub cor: f64,
}

/// One measured (or given) kernel at a sensor point. A file handed to `deblur` may hold
/// the Gaussian only, the kernel only, or both.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelSample {
    pub x: f64,
    pub y: f64,
    pub channel: Channel,
    /// The robust fit.
    #[serde(default)]
    pub cxx: Option<f64>,
    #[serde(default)]
    pub cyy: Option<f64>,
    #[serde(default)]
    pub cor: Option<f64>,
    /// The chart square it was measured on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub row: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub col: Option<usize>,
    /// The maximum-likelihood (moment) fit, kept for comparison.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ml: Option<GaussianRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kernel: Option<KernelData>,
}

/// A square × channel whose estimate failed, with the reason (never a number).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FailedSample {
    pub row: usize,
    pub col: usize,
    pub x: f64,
    pub y: f64,
    pub channel: Channel,
    pub reason: String,
}

/// The kernels file; unknown fields are ignored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelsFile {
    #[serde(default)]
    pub schema: String,
    pub width: usize,
    pub height: usize,
    #[serde(default)]
    pub focal_mm: Option<f64>,
    #[serde(default)]
    pub f_number: Option<f64>,
    #[serde(default = "default_oversample")]
    pub oversample: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identity: Option<CameraIdentity>,
    /// The shot it was measured on, where the pipeline wrote it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<crate::pipeline::ShotRecord>,
    pub samples: Vec<KernelSample>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub failed: Vec<FailedSample>,
}

fn default_oversample() -> usize {
    3
}

#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct KernelsFileError {
    pub path: String,
    pub reason: String,
}

impl KernelsFile {
    /// The file form of a shot's estimates; `with_kernels` adds the kernel arrays.
    #[must_use]
    pub fn from_shot(
        shot: &ShotKernels,
        focal_mm: Option<f64>,
        f_number: Option<f64>,
        identity: Option<CameraIdentity>,
        with_kernels: bool,
    ) -> Self {
        let mut samples = Vec::new();
        let mut failed = Vec::new();
        for sq in &shot.squares {
            for (channel, est) in &sq.estimates {
                match est {
                    Ok(e) => {
                        let (r, m) = (e.fit.robust, e.fit.ml);
                        samples.push(KernelSample {
                            x: e.centre[0],
                            y: e.centre[1],
                            channel: e.channel,
                            cxx: Some(r.sigma_x),
                            cyy: Some(r.sigma_y),
                            cor: Some(r.rho),
                            row: Some(sq.row),
                            col: Some(sq.col),
                            ml: Some(GaussianRecord {
                                cxx: m.sigma_x,
                                cyy: m.sigma_y,
                                cor: m.rho,
                            }),
                            kernel: with_kernels.then(|| KernelData {
                                size: e.kernel.size,
                                data: e.kernel.data.clone(),
                            }),
                        });
                    }
                    Err(reason) => failed.push(FailedSample {
                        row: sq.row,
                        col: sq.col,
                        x: sq.centre[0],
                        y: sq.centre[1],
                        channel: *channel,
                        reason: reason.to_string(),
                    }),
                }
            }
        }
        Self {
            schema: KERNELS.tag(),
            width: shot.width,
            height: shot.height,
            focal_mm,
            f_number,
            oversample: shot.oversample,
            identity,
            source: None,
            samples,
            failed,
        }
    }

    /// Reads and checks a kernels file.
    ///
    /// # Errors
    /// A one-line reason naming the file when it cannot be read, is not a kernels file,
    /// or holds a malformed kernel.
    pub fn load(path: &Path) -> Result<Self, KernelsFileError> {
        let err = |reason: String| KernelsFileError {
            path: path.display().to_string(),
            reason,
        };
        let text = crate::io::read_json_text(path).map_err(|e| KernelsFileError {
            path: path.display().to_string(),
            reason: match e {
                crate::io::ReadError::Io { source, .. } => source.to_string(),
                too_large => too_large.to_string(),
            },
        })?;
        Self::from_json(&text).map_err(err)
    }

    /// Parses and checks a kernels file's text.
    ///
    /// # Errors
    /// The reason it is not a usable kernels file.
    pub fn from_json(text: &str) -> Result<Self, String> {
        KERNELS.version_of_json(text).map_err(|e| e.to_string())?;
        let f: KernelsFile =
            serde_json::from_str(text).map_err(|e| format!("not a kernels file: {e}"))?;
        f.check()?;
        Ok(f)
    }

    /// # Errors
    /// The reason the contents are unusable.
    pub fn check(&self) -> Result<(), String> {
        use crate::limits::{MAX_IMAGE_SIDE, MAX_KERNEL_SIDE, MAX_OVERSAMPLE};
        KERNELS
            .version_of(Some(&self.schema))
            .map_err(|e| e.to_string())?;
        if !(1..=MAX_OVERSAMPLE).contains(&self.oversample) {
            return Err(format!(
                "oversample {} is not 1–{MAX_OVERSAMPLE}",
                self.oversample
            ));
        }
        if !(1..=MAX_IMAGE_SIDE).contains(&self.width)
            || !(1..=MAX_IMAGE_SIDE).contains(&self.height)
        {
            return Err(format!(
                "sensor size {} × {}: each side must be 1–{MAX_IMAGE_SIDE} px",
                self.width, self.height
            ));
        }
        for (i, s) in self.samples.iter().enumerate() {
            if let Some(k) = &s.kernel {
                if k.size > MAX_KERNEL_SIDE {
                    return Err(format!(
                        "sample {i}: a {0} × {0} kernel is above the limit of {MAX_KERNEL_SIDE}",
                        k.size
                    ));
                }
                if k.size % 2 == 0 || k.data.len() != k.size * k.size {
                    return Err(format!(
                        "sample {i}: kernel must be odd-sized with size² values"
                    ));
                }
            }
        }
        Ok(())
    }
}

impl KernelSample {
    /// The stored kernel array as a [`Kernel`] at the file's oversampling.
    #[must_use]
    pub fn kernel_at(&self, oversample: usize) -> Option<Kernel> {
        self.kernel.as_ref().map(|k| Kernel {
            size: k.size,
            oversample,
            data: k.data.clone(),
        })
    }
}
