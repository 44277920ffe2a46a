//! Where a tile's kernel comes from: anything that answers "the kernel of this channel
//! at this sensor point" — a lens profile, a kernels file, the simulator's truth.

use crate::model::{PlacedShape, ShapeModel};
use crate::plane::Channel;
use crate::psf::{Gaussian2, Kernel};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error("{path}: {reason}")]
    File { path: String, reason: String },
    #[error("no kernel for channel {0}")]
    NoKernel(Channel),
    #[error("{0}")]
    Other(String),
}

/// A kernel that is a Gaussian rendered at its mean: exactly
/// `gaussian.kernel_at(oversample, mean)`, so a few numbers say all of it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlacedGaussian {
    pub gaussian: Gaussian2,
    /// Where its mean lies, px from the kernel's centre.
    pub mean: [f64; 2],
    pub oversample: usize,
}

/// A kernel a kernel-shape model predicts, as its parts: exactly
/// `model.kernel_of(&placed, oversample)`, so the model's components (the same for
/// every tile) and a few numbers a tile say all of it.
#[derive(Clone, Debug)]
pub struct ShapedKernel<'a> {
    pub model: &'a ShapeModel,
    pub placed: PlacedShape,
    pub oversample: usize,
}

/// The pixel-level kernel (any oversample) of `channel` at sensor point (x, y).
pub trait KernelSource: Sync {
    /// # Errors
    /// When the source has nothing for this channel or point.
    fn kernel_at(&self, channel: Channel, x: f64, y: f64) -> Result<Kernel, SourceError>;

    /// The same kernel as a [`PlacedGaussian`] where it is one (the GPU path then makes
    /// its taps on the device); `None`, the default, where it is not or the source
    /// does not say.
    ///
    /// # Errors
    /// As [`Self::kernel_at`].
    fn placed_gaussian(
        &self,
        _channel: Channel,
        _x: f64,
        _y: f64,
    ) -> Result<Option<PlacedGaussian>, SourceError> {
        Ok(None)
    }

    /// The same kernel as a [`ShapedKernel`] where a shape model predicts it (the GPU
    /// path then makes its taps on the device); `None`, the default, where not.
    ///
    /// # Errors
    /// As [`Self::kernel_at`].
    fn shaped_kernel(
        &self,
        _channel: Channel,
        _x: f64,
        _y: f64,
    ) -> Result<Option<ShapedKernel<'_>>, SourceError> {
        Ok(None)
    }
}

impl<F> KernelSource for F
where
    F: Fn(Channel, f64, f64) -> Kernel + Sync,
{
    fn kernel_at(&self, channel: Channel, x: f64, y: f64) -> Result<Kernel, SourceError> {
        Ok(self(channel, x, y))
    }
}

/// One kernel everywhere.
#[derive(Clone, Debug)]
pub struct ConstantKernel(pub Kernel);

impl KernelSource for ConstantKernel {
    fn kernel_at(&self, _channel: Channel, _x: f64, _y: f64) -> Result<Kernel, SourceError> {
        Ok(self.0.clone())
    }
}

pub use crate::kernel::file::{KernelData, KernelSample, KernelsFile};

/// Reads a kernels file for deblurring.
///
/// # Errors
/// A one-line reason naming the file.
pub fn load_kernels(path: &Path) -> Result<KernelsFile, SourceError> {
    KernelsFile::load(path).map_err(|e| SourceError::File {
        path: e.path,
        reason: e.reason,
    })
}

pub use crate::limits::MAX_KERNEL_RADIUS_PX;

/// Why a kernels-file sample cannot be used, or `None`.
fn sample_problem(
    s: &KernelSample,
    oversample: usize,
    width: usize,
    height: usize,
) -> Option<String> {
    let (w, h) = (width as f64, height as f64);
    if !(s.x.is_finite() && s.y.is_finite())
        || s.x < -w
        || s.x > 2.0 * w
        || s.y < -h
        || s.y > 2.0 * h
    {
        return Some(format!("position ({}, {}) is off the sensor", s.x, s.y));
    }
    let gaussian = match (s.cxx, s.cyy) {
        (Some(sx), Some(sy)) => {
            let rho = s.cor.unwrap_or(0.0);
            let ok = |v: f64| v.is_finite() && v > 0.0 && v <= MAX_KERNEL_RADIUS_PX / 4.0;
            if !(ok(sx) && ok(sy)) {
                return Some(format!("cxx, cyy = {sx}, {sy} must be positive σs (px)"));
            }
            if !(rho.is_finite() && rho.abs() < 1.0) {
                return Some(format!("cor = {rho} must lie in (−1, 1)"));
            }
            true
        }
        (None, None) => false,
        _ => return Some("cxx and cyy must come together".into()),
    };
    if let Some(k) = &s.kernel {
        if k.size as f64 / 2.0 / oversample as f64 > MAX_KERNEL_RADIUS_PX {
            return Some(format!(
                "a {0} × {0} kernel at {oversample}× is wider than {MAX_KERNEL_RADIUS_PX} px",
                k.size
            ));
        }
        if k.data.iter().any(|v| !v.is_finite()) {
            return Some("the kernel holds a non-finite value".into());
        }
        if k.data.iter().sum::<f64>() <= 0.0 {
            return Some("the kernel does not sum to a positive value".into());
        }
    } else if !gaussian {
        return Some("neither a Gaussian (cxx, cyy) nor a kernel".into());
    }
    None
}

/// Which half of a kernels-file sample to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Prefer {
    /// The non-parametric kernel where present, the Gaussian otherwise.
    #[default]
    Kernel,
    /// The Gaussian where present, the kernel otherwise.
    Gaussian,
}

/// Kernels at scattered sensor points, interpolated between the nearest samples of the
/// channel: Gaussians by their covariances, arrays by a weighted blend.
#[derive(Clone, Debug)]
pub struct ScatteredKernels {
    pub file: KernelsFile,
    pub prefer: Prefer,
    /// How many nearest samples are blended.
    pub neighbours: usize,
}

impl ScatteredKernels {
    /// Kernels from a file the caller vouches for (see [`Self::checked`]).
    #[must_use]
    pub fn new(file: KernelsFile, prefer: Prefer) -> Self {
        Self {
            file,
            prefer,
            neighbours: 4,
        }
    }

    /// Kernels from a file read from disk: every sample must be usable, `origin` names
    /// the file in the error.
    ///
    /// # Errors
    /// No samples, or the first unusable sample and why.
    pub fn checked(file: KernelsFile, prefer: Prefer, origin: &str) -> Result<Self, SourceError> {
        let err = |reason: String| SourceError::File {
            path: origin.into(),
            reason,
        };
        if file.samples.is_empty() {
            return Err(err("no kernel samples".into()));
        }
        for (i, s) in file.samples.iter().enumerate() {
            if let Some(p) = sample_problem(s, file.oversample, file.width, file.height) {
                return Err(err(format!("sample {i} ({}): {p}", s.channel)));
            }
        }
        Ok(Self::new(file, prefer))
    }

    fn sample_kernel(&self, s: &KernelSample) -> Option<Kernel> {
        let gaussian = match (s.cxx, s.cyy) {
            (Some(sx), Some(sy)) if sx > 0.0 && sy > 0.0 => Some(Gaussian2 {
                sigma_x: sx,
                sigma_y: sy,
                rho: s.cor.unwrap_or(0.0),
            }),
            _ => None,
        };
        let array = s.kernel.as_ref().map(|k| {
            let mut k = Kernel {
                size: k.size,
                oversample: self.file.oversample,
                data: k.data.clone(),
            };
            k.normalise();
            k
        });
        match self.prefer {
            Prefer::Kernel => array.or_else(|| gaussian.map(|g| g.kernel(self.file.oversample))),
            Prefer::Gaussian => gaussian.map(|g| g.kernel(self.file.oversample)).or(array),
        }
    }
}

impl KernelSource for ScatteredKernels {
    fn kernel_at(&self, channel: Channel, x: f64, y: f64) -> Result<Kernel, SourceError> {
        // A G1/G2 or Y plane falls back to G, then to any channel the file has.
        let mut pool: Vec<&KernelSample> = self
            .file
            .samples
            .iter()
            .filter(|s| s.channel == channel)
            .collect();
        if pool.is_empty() {
            pool = self
                .file
                .samples
                .iter()
                .filter(|s| s.channel == Channel::G)
                .collect();
        }
        if pool.is_empty() {
            pool = self.file.samples.iter().collect();
        }
        let mut near: Vec<(f64, &KernelSample)> = pool
            .into_iter()
            .map(|s| ((s.x - x).powi(2) + (s.y - y).powi(2), s))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        near.truncate(self.neighbours.max(1));
        let gaussians_only =
            self.prefer == Prefer::Gaussian || near.iter().all(|(_, s)| s.kernel.is_none());
        let all_gaussian = near.iter().all(|(_, s)| s.cxx.is_some() && s.cyy.is_some());
        // Inverse squared distance weights; a sample right on the point dominates.
        let weights: Vec<f64> = near.iter().map(|(d2, _)| 1.0 / (d2 + 1e-6)).collect();
        let wsum: f64 = weights.iter().sum();
        if near.is_empty() {
            return Err(SourceError::NoKernel(channel));
        }
        if gaussians_only && all_gaussian {
            let (mut vx, mut vy, mut cxy) = (0.0, 0.0, 0.0);
            for ((_, s), w) in near.iter().zip(&weights) {
                let g = Gaussian2 {
                    sigma_x: s.cxx.unwrap_or(0.0),
                    sigma_y: s.cyy.unwrap_or(0.0),
                    rho: s.cor.unwrap_or(0.0),
                };
                vx += w * g.sigma_x.powi(2);
                vy += w * g.sigma_y.powi(2);
                cxy += w * g.cov_xy();
            }
            return Ok(Gaussian2::from_covariance(vx / wsum, vy / wsum, cxy / wsum)
                .kernel(self.file.oversample));
        }
        let kernels: Vec<(Kernel, f64)> = near
            .iter()
            .zip(&weights)
            .filter_map(|((_, s), &w)| self.sample_kernel(s).map(|k| (k, w)))
            .collect();
        let size = kernels
            .iter()
            .map(|(k, _)| k.size)
            .max()
            .ok_or(SourceError::NoKernel(channel))?;
        let mut data = vec![0.0; size * size];
        for (k, w) in &kernels {
            let off = (size - k.size) / 2;
            for j in 0..k.size {
                for i in 0..k.size {
                    data[(j + off) * size + i + off] += w * k.at(i, j);
                }
            }
        }
        let mut k = Kernel {
            size,
            oversample: self.file.oversample,
            data,
        };
        k.normalise();
        Ok(k)
    }
}

/// The kernels a lens profile predicts at one focal length and aperture: each tile gets
/// the pixel-level kernel of its centre at 3× — the Gaussian, or the Gaussian with the
/// shape model's predicted shape. A channel the profile lacks (a monochrome photo, say)
/// takes green's.
pub struct ProfileKernels {
    pub profile: crate::profile::Profile,
    pub setting: crate::plane::LensSetting,
    pub model: crate::model::KernelModel,
    /// Whether the kernels carry the lens's lateral colour, so deblurring corrects it.
    pub lateral: crate::model::LateralColour,
}

impl ProfileKernels {
    /// The profile's kernels in the model it recommends (its shape model where it
    /// holds one).
    #[must_use]
    pub fn new(profile: crate::profile::Profile, setting: crate::plane::LensSetting) -> Self {
        let model = profile.kernel_model();
        Self {
            profile,
            setting,
            model,
            lateral: crate::model::LateralColour::default(),
        }
    }

    /// The profile's kernels in a chosen model.
    ///
    /// # Errors
    /// The shape model asked of a profile without one.
    pub fn with_model(
        profile: crate::profile::Profile,
        setting: crate::plane::LensSetting,
        model: crate::model::KernelModel,
    ) -> Result<Self, crate::profile::ProfileError> {
        if model == crate::model::KernelModel::Shape && profile.shape.is_none() {
            return Err(crate::profile::ProfileError::NoShapeModel);
        }
        Ok(Self {
            profile,
            setting,
            model,
            lateral: crate::model::LateralColour::default(),
        })
    }

    /// The same kernels, correcting or keeping the lens's lateral colour.
    #[must_use]
    pub fn with_lateral(self, lateral: crate::model::LateralColour) -> Self {
        Self { lateral, ..self }
    }

    /// What the kernels do with lateral colour, where the profile knows where each
    /// channel's kernels are centred.
    #[must_use]
    pub fn lateral_colour(&self) -> Option<crate::model::LateralColour> {
        self.profile.place.as_ref().map(|_| self.lateral)
    }
}

impl ProfileKernels {
    /// The channel whose kernels a plane of `channel` takes: its own, else green's.
    fn channel_for(&self, channel: Channel) -> Channel {
        if self.profile.channels().contains(&channel) {
            channel
        } else {
            Channel::G
        }
    }
}

impl KernelSource for ProfileKernels {
    fn kernel_at(&self, channel: Channel, x: f64, y: f64) -> Result<Kernel, SourceError> {
        let ch = self.channel_for(channel);
        self.profile
            .predict_kernel(self.model, self.lateral, ch, x, y, self.setting)
            .map_err(|e| SourceError::Other(e.to_string()))
    }

    /// The Gaussian model's kernels are placed Gaussians; the shape model's are not.
    fn placed_gaussian(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
    ) -> Result<Option<PlacedGaussian>, SourceError> {
        if self.model != crate::model::KernelModel::Gaussian {
            return Ok(None);
        }
        let ch = self.channel_for(channel);
        let (gaussian, mean) = self
            .profile
            .placed_gaussian(self.lateral, ch, x, y, self.setting)
            .map_err(|e| SourceError::Other(e.to_string()))?;
        Ok(Some(PlacedGaussian {
            gaussian,
            mean,
            oversample: crate::profile::KERNEL_OVERSAMPLE,
        }))
    }

    /// The shape model's kernels are shaped kernels; the Gaussian model's are not.
    fn shaped_kernel(
        &self,
        channel: Channel,
        x: f64,
        y: f64,
    ) -> Result<Option<ShapedKernel<'_>>, SourceError> {
        if self.model != crate::model::KernelModel::Shape {
            return Ok(None);
        }
        let ch = self.channel_for(channel);
        let (model, placed) = self
            .profile
            .placed_shape(self.lateral, ch, x, y, self.setting)
            .map_err(|e| SourceError::Other(e.to_string()))?;
        Ok(Some(ShapedKernel {
            model,
            placed,
            oversample: crate::profile::KERNEL_OVERSAMPLE,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(x: f64, y: f64, s: f64) -> KernelSample {
        KernelSample {
            x,
            y,
            channel: Channel::G,
            cxx: Some(s),
            cyy: Some(s),
            cor: Some(0.0),
            row: None,
            col: None,
            ml: None,
            kernel: None,
        }
    }

    #[test]
    fn gaussians_interpolate_between_samples() {
        let file = KernelsFile::of_samples(
            100,
            100,
            vec![sample(0.0, 0.0, 1.0), sample(100.0, 0.0, 2.0)],
        );
        let src = ScatteredKernels {
            neighbours: 2,
            ..ScatteredKernels::new(file, Prefer::Gaussian)
        };
        let at = |x: f64| {
            src.kernel_at(Channel::G, x, 0.0)
                .map(|k| k.moments().var_x.sqrt())
                .unwrap_or(0.0)
        };
        assert!((at(0.0) - 1.0).abs() < 0.01);
        assert!((at(100.0) - 2.0).abs() < 0.01);
        let mid = at(50.0);
        assert!((mid - (2.5f64).sqrt()).abs() < 0.02, "{mid}");
        // Red falls back to green.
        assert!(src.kernel_at(Channel::R, 0.0, 0.0).is_ok());
    }
}
