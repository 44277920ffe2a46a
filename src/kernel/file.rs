//! The kernels file (`lensblur.kernels/1`, docs/formats.md): what `lensblur kernels`
//! writes, and what calibration and deblurring read. One type for both directions so
//! the writer and its readers cannot drift apart.

use super::ShotKernels;
use crate::plane::{CameraIdentity, Channel, LensSetting};
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

/// The kernels file; unknown fields are ignored. Written with each sample's MTF50
/// beside its Gaussian (see the `Serialize` impl below).
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct KernelsFile {
    #[serde(default)]
    pub schema: String,
    pub width: usize,
    pub height: usize,
    #[serde(default)]
    pub focal_mm: Option<f64>,
    #[serde(default)]
    pub f_number: Option<f64>,
    /// Where the lens was focused, where the shot's file says.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus_distance_m: Option<crate::raw::FocusDistance>,
    #[serde(default = "default_oversample")]
    pub oversample: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identity: Option<CameraIdentity>,
    /// The shot it was measured on, where the pipeline wrote it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<crate::shot_file::ShotRecord>,
    /// What the shot was (RAW, linear or developed picture), where the pipeline wrote it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub picture: Option<crate::plane::PictureKind>,
    pub samples: Vec<KernelSample>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub failed: Vec<FailedSample>,
}

/// The file as written: every field of [`KernelsFile`], each sample with its `mtf50`
/// derived from its Gaussian. Derived here, on writing, so it can never disagree with
/// the σs beside it; readers ignore it.
#[derive(Serialize)]
struct FileOut<'a> {
    schema: &'a str,
    width: usize,
    height: usize,
    focal_mm: Option<f64>,
    f_number: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    focus_distance_m: Option<crate::raw::FocusDistance>,
    oversample: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    identity: Option<&'a CameraIdentity>,
    #[serde(skip_serializing_if = "Option::is_none")]
    source: Option<&'a crate::shot_file::ShotRecord>,
    #[serde(skip_serializing_if = "Option::is_none")]
    picture: Option<crate::plane::PictureKind>,
    samples: Vec<SampleOut<'a>>,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    failed: &'a [FailedSample],
}

#[derive(Serialize)]
struct SampleOut<'a> {
    #[serde(flatten)]
    sample: &'a KernelSample,
    #[serde(skip_serializing_if = "Option::is_none")]
    mtf50: Option<crate::psf::Mtf50Record>,
}

impl Serialize for KernelsFile {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        FileOut {
            schema: &self.schema,
            width: self.width,
            height: self.height,
            focal_mm: self.focal_mm,
            f_number: self.f_number,
            focus_distance_m: self.focus_distance_m,
            oversample: self.oversample,
            identity: self.identity.as_ref(),
            source: self.source.as_ref(),
            picture: self.picture,
            samples: self
                .samples
                .iter()
                .map(|sample| SampleOut {
                    sample,
                    mtf50: sample
                        .gaussian()
                        .and_then(|g| g.mtf50())
                        .map(|m| m.record(self.height)),
                })
                .collect(),
            failed: &self.failed,
        }
        .serialize(serializer)
    }
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
    /// A file of `samples` on a `width × height` sensor at 3× (the estimator's
    /// default), with no setting, camera or shot recorded yet.
    #[must_use]
    pub fn of_samples(width: usize, height: usize, samples: Vec<KernelSample>) -> Self {
        Self {
            schema: KERNELS.tag(),
            width,
            height,
            focal_mm: None,
            f_number: None,
            focus_distance_m: None,
            oversample: default_oversample(),
            identity: None,
            source: None,
            picture: None,
            samples,
            failed: Vec::new(),
        }
    }

    /// The kernels of several shots at one setting as one field over the sensor: a
    /// small chart shot at several positions measures the frame a part per shot. Every
    /// sample keeps its sensor position; the first file's header is kept. `None` when
    /// the files are of different sensors, oversampling or settings, which one field
    /// cannot hold.
    #[must_use]
    pub fn merged(files: &[&KernelsFile]) -> Option<KernelsFile> {
        let (first, rest) = files.split_first()?;
        let same = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (Some(a), Some(b)) => LensSetting::same_value(a, b),
            (None, None) => true,
            _ => false,
        };
        if rest.iter().any(|f| {
            (f.width, f.height, f.oversample) != (first.width, first.height, first.oversample)
                || !same(f.focal_mm, first.focal_mm)
                || !same(f.f_number, first.f_number)
        }) {
            return None;
        }
        let mut out = KernelsFile {
            source: None,
            ..(*first).clone()
        };
        for f in rest {
            out.samples.extend(f.samples.iter().cloned());
            out.failed.extend(f.failed.iter().cloned());
        }
        Some(out)
    }

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
            focus_distance_m: None,
            oversample: shot.oversample,
            identity,
            source: None,
            picture: None,
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
    /// The robust fit as a Gaussian, where the sample holds all three of C_xx, C_yy,
    /// C_or (the samples calibration uses).
    #[must_use]
    pub fn gaussian(&self) -> Option<crate::psf::Gaussian2> {
        Some(crate::psf::Gaussian2 {
            sigma_x: self.cxx?,
            sigma_y: self.cyy?,
            rho: self.cor?,
        })
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    /// A G sample of σ 1 px, isotropic, on square (0, 0), at (x, 20).
    fn unit_sample(x: f64) -> KernelSample {
        KernelSample {
            x,
            y: 20.0,
            channel: Channel::G,
            cxx: Some(1.0),
            cyy: Some(1.0),
            cor: Some(0.0),
            row: Some(0),
            col: Some(0),
            ml: None,
            kernel: None,
        }
    }

    #[test]
    fn shots_at_one_setting_merge_into_one_field() {
        let shot = |x: f64, focal: f64, width: usize| KernelsFile {
            focal_mm: Some(focal),
            f_number: Some(4.0),
            ..KernelsFile::of_samples(width, 2000, vec![unit_sample(x)])
        };
        let (a, b) = (shot(10.0, 24.0, 3000), shot(2900.0, 24.0, 3000));
        let m = KernelsFile::merged(&[&a, &b]).expect("one field");
        let xs: Vec<f64> = m.samples.iter().map(|s| s.x).collect();
        assert_eq!(xs, [10.0, 2900.0], "each sample where it was measured");
        assert!(KernelsFile::merged(&[&a, &shot(5.0, 50.0, 3000)]).is_none());
        assert!(KernelsFile::merged(&[&a, &shot(5.0, 24.0, 4000)]).is_none());
        assert!(KernelsFile::merged(&[]).is_none());
    }

    #[test]
    fn samples_are_written_with_their_mtf50_and_read_back_unchanged() {
        let file = KernelsFile {
            focal_mm: Some(50.0),
            f_number: Some(4.0),
            ..KernelsFile::of_samples(
                3000,
                2000,
                vec![
                    unit_sample(10.0),
                    KernelSample {
                        x: 30.0,
                        y: 20.0,
                        channel: Channel::R,
                        cxx: None,
                        cyy: None,
                        cor: None,
                        row: None,
                        col: None,
                        ml: None,
                        kernel: Some(KernelData {
                            size: 1,
                            data: vec![1.0],
                        }),
                    },
                ],
            )
        };
        let text = serde_json::to_string(&file).expect("json");
        let v: serde_json::Value = serde_json::from_str(&text).expect("json");
        let m = &v["samples"][0]["mtf50"];
        // σ = 1 px isotropic: √(ln 2 / 2) / π cycles/px, × 2000 px of picture height.
        assert!((m["worst"].as_f64().expect("worst") - 0.187_390).abs() < 1e-6);
        assert!((m["isotropic_lp_ph"].as_f64().expect("lp/ph") - 374.78).abs() < 0.01);
        assert!(
            v["samples"][1].get("mtf50").is_none(),
            "no Gaussian, no MTF50"
        );
        assert_eq!(v["samples"][0]["cxx"], 1.0);
        assert_eq!(KernelsFile::from_json(&text).expect("read back"), file);
    }
}
