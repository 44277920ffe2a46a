//! The measured samples of a calibration session, and what they say about it: its
//! distinct settings, the normalisation they imply, the orders in f and a they can
//! support, and the scale of the chart's squares.

use super::ModelError;
use super::basis::{Normalisation, check_order, model_basis};
use crate::plane::{CameraIdentity, Channel, LensSetting, PictureKind};
use crate::psf::Gaussian2;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One measured Gaussian: a square of a shot, one channel.
#[derive(Clone, Debug, PartialEq)]
pub struct BlurSample {
    pub shot: usize,
    pub x: f64,
    pub y: f64,
    /// The chart square (row, column) it was measured on, where known: it gives the
    /// imaged square width even when only every other square was measured.
    pub square: Option<[usize; 2]>,
    pub focal_mm: f64,
    pub f_number: f64,
    pub channel: Channel,
    pub gaussian: Gaussian2,
    /// The measured 3× kernel the Gaussian was fitted to, where the session kept it:
    /// the kernel-shape model learns from these. Shared, as folds copy samples.
    pub kernel: Option<std::sync::Arc<crate::psf::Kernel>>,
}

impl BlurSample {
    /// C_xx, C_yy, C_or in that order.
    #[must_use]
    pub fn params(&self) -> [f64; 3] {
        [
            self.gaussian.sigma_x,
            self.gaussian.sigma_y,
            self.gaussian.rho,
        ]
    }

    /// The setting of the shot it was measured in.
    #[must_use]
    pub fn setting(&self) -> LensSetting {
        LensSetting {
            focal_mm: self.focal_mm,
            f_number: self.f_number,
        }
    }
}

/// What is known of one shot of a calibration session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShotInfo {
    pub name: String,
    pub focal_mm: f64,
    pub f_number: f64,
    /// Where the lens was focused, where the shot's file says.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus_distance_m: Option<crate::raw::FocusDistance>,
}

impl ShotInfo {
    #[must_use]
    pub fn setting(&self) -> LensSetting {
        LensSetting {
            focal_mm: self.focal_mm,
            f_number: self.f_number,
        }
    }
}

/// The measured Gaussians of a calibration session.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub width: usize,
    pub height: usize,
    pub identity: CameraIdentity,
    /// What the shots were, where their kernels files say: developed if any one was
    /// (a profile of such shots knows no single tone curve).
    pub picture: Option<PictureKind>,
    pub samples: Vec<BlurSample>,
    pub shots: Vec<ShotInfo>,
}

/// A stored kernel as the shape model takes it: odd, at least 3 × 3, finite, summing
/// to a positive value (normalised to 1); anything else is left out rather than
/// trusted.
fn measured_kernel(
    k: &crate::kernel::file::KernelData,
    oversample: usize,
) -> Option<std::sync::Arc<crate::psf::Kernel>> {
    let sum: f64 = k.data.iter().sum();
    let usable = k.size % 2 == 1
        && k.size >= 3
        && oversample >= 1
        && k.data.len() == k.size * k.size
        && k.data.iter().all(|v| v.is_finite())
        && sum > 0.0;
    usable.then(|| {
        let mut kernel = crate::psf::Kernel {
            size: k.size,
            oversample,
            data: k.data.clone(),
        };
        kernel.normalise();
        std::sync::Arc::new(kernel)
    })
}

/// The names of the three modelled parameters, in the order of [`BlurSample::params`].
pub const PARAM_NAMES: [&str; 3] = ["cxx", "cyy", "cor"];

impl Dataset {
    /// An empty session on a `width × height` sensor.
    #[must_use]
    pub fn new(width: usize, height: usize, identity: CameraIdentity) -> Self {
        Self {
            width,
            height,
            identity,
            picture: None,
            samples: Vec::new(),
            shots: Vec::new(),
        }
    }

    /// Adds one shot's samples (their `shot` field is overwritten) and returns its index.
    pub fn push_shot(
        &mut self,
        info: ShotInfo,
        samples: impl IntoIterator<Item = BlurSample>,
    ) -> usize {
        let shot = self.shots.len();
        for mut s in samples {
            s.shot = shot;
            s.focal_mm = info.focal_mm;
            s.f_number = info.f_number;
            self.samples.push(s);
        }
        self.shots.push(info);
        shot
    }

    /// Reads `lensblur.kernels/1` files, one shot each. `settings[i]`, where given,
    /// overrides the file's own focal length and f-number (a manifest's values).
    /// Entries with `"status": "failed"` or without numbers are skipped.
    ///
    /// # Errors
    /// A file that cannot be read or parsed, a wrong schema, sensors of different sizes,
    /// or a shot whose setting is unknown (named in the error).
    pub fn from_kernels_files(
        paths: &[&Path],
        settings: &[Option<LensSetting>],
    ) -> Result<Self, ModelError> {
        let files = paths
            .iter()
            .map(|path| {
                crate::kernel::file::KernelsFile::load(path).map_err(|e| ModelError::File {
                    path: path.display().to_string(),
                    reason: e.reason,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
        let shots: Vec<(&str, &crate::kernel::file::KernelsFile, Option<LensSetting>)> = files
            .iter()
            .enumerate()
            .map(|(i, kf)| (names[i].as_str(), kf, settings.get(i).copied().flatten()))
            .collect();
        let mut ds = Self::from_kernels(&shots)?;
        // A shot read from a file is named by the file.
        for (info, path) in ds.shots.iter_mut().zip(paths) {
            info.name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
        }
        Ok(ds)
    }

    /// The dataset of kernels already in memory, one `(name, file, setting)` per shot;
    /// the given setting overrides the file's, and errors name the shot by `name`.
    ///
    /// # Errors
    /// A shot whose setting is unknown, shots of different cameras or lenses or sensor
    /// sizes, or no shot.
    pub fn from_kernels(
        shots: &[(&str, &crate::kernel::file::KernelsFile, Option<LensSetting>)],
    ) -> Result<Self, ModelError> {
        let mut ds: Option<Dataset> = None;
        for &(name, kf, given) in shots {
            let focal_mm = given.map(|s| s.focal_mm).or(kf.focal_mm);
            let f_number = given.map(|s| s.f_number).or(kf.f_number);
            let (Some(focal_mm), Some(f_number)) = (focal_mm, f_number) else {
                return Err(ModelError::UnknownSetting { shot: name.into() });
            };
            if !(focal_mm.is_finite() && focal_mm > 0.0 && f_number.is_finite() && f_number > 0.0) {
                return Err(ModelError::UnknownSetting { shot: name.into() });
            }
            let d = ds.get_or_insert_with(|| {
                Dataset::new(kf.width, kf.height, kf.identity.clone().unwrap_or_default())
            });
            if let Some(id) = &kf.identity {
                merge_identity(&mut d.identity, id).map_err(|(field, a, b)| {
                    ModelError::MixedIdentity {
                        field,
                        a,
                        b,
                        shot: name.into(),
                    }
                })?;
            }
            d.picture = match (d.picture, kf.picture) {
                (Some(a), Some(b))
                    if a == PictureKind::Developed || b == PictureKind::Developed =>
                {
                    Some(PictureKind::Developed)
                }
                (a, b) => a.or(b),
            };
            if (d.width, d.height) != (kf.width, kf.height) {
                return Err(ModelError::SensorMismatch {
                    a: format!("{}×{}", d.width, d.height),
                    b: format!("{}×{} in {name}", kf.width, kf.height),
                });
            }
            let samples: Vec<BlurSample> = kf
                .samples
                .iter()
                .filter_map(|e| {
                    let (cxx, cyy, cor) = (e.cxx?, e.cyy?, e.cor?);
                    (cxx.is_finite() && cyy.is_finite() && cor.is_finite()).then_some(BlurSample {
                        shot: 0,
                        x: e.x,
                        y: e.y,
                        square: e.row.zip(e.col).map(|(r, c)| [r, c]),
                        focal_mm,
                        f_number,
                        channel: e.channel,
                        gaussian: Gaussian2 {
                            sigma_x: cxx,
                            sigma_y: cyy,
                            rho: cor,
                        },
                        kernel: e
                            .kernel
                            .as_ref()
                            .and_then(|k| measured_kernel(k, kf.oversample)),
                    })
                })
                .collect();
            d.push_shot(
                ShotInfo {
                    name: name.into(),
                    focal_mm,
                    f_number,
                    focus_distance_m: kf.focus_distance_m,
                },
                samples,
            );
        }
        ds.ok_or(ModelError::Empty)
    }

    /// Checks every shot's setting is a real one.
    ///
    /// # Errors
    /// [`ModelError::UnknownSetting`] naming the first shot without one.
    pub fn validate(&self) -> Result<(), ModelError> {
        for s in &self.shots {
            if !(s.focal_mm.is_finite()
                && s.focal_mm > 0.0
                && s.f_number.is_finite()
                && s.f_number > 0.0)
            {
                return Err(ModelError::UnknownSetting {
                    shot: s.name.clone(),
                });
            }
        }
        if self.samples.is_empty() {
            return Err(ModelError::Empty);
        }
        Ok(())
    }

    /// The samples of one channel, in the order they were measured.
    pub(crate) fn samples_of(&self, channel: Channel) -> Vec<&BlurSample> {
        self.samples
            .iter()
            .filter(|s| s.channel == channel)
            .collect()
    }

    /// The channels present, sorted.
    #[must_use]
    pub fn channels(&self) -> Vec<Channel> {
        let mut c: Vec<Channel> = self.samples.iter().map(|s| s.channel).collect();
        c.sort();
        c.dedup();
        c
    }

    /// Distinct focal lengths and f-numbers (sorted), merged by
    /// [`LensSetting::same_value`].
    #[must_use]
    pub fn distinct_settings(&self) -> (Vec<f64>, Vec<f64>) {
        (
            LensSetting::distinct_values(self.shots.iter().map(|s| s.focal_mm)),
            LensSetting::distinct_values(self.shots.iter().map(|s| s.f_number)),
        )
    }

    /// The normalisation of this session: the sensor and the calibrated ranges.
    #[must_use]
    pub fn normalisation(&self) -> Normalisation {
        let (f, a) = self.distinct_settings();
        Normalisation {
            width: self.width,
            height: self.height,
            focal_range_mm: [
                f.first().copied().unwrap_or(0.0),
                f.last().copied().unwrap_or(0.0),
            ],
            f_number_range: [
                a.first().copied().unwrap_or(1.0),
                a.last().copied().unwrap_or(1.0),
            ],
            sampled_extent_px: self.sampled_extent_px(),
        }
    }

    /// The bounding box `[x0, y0, x1, y1]` of the sample positions, pixels.
    #[must_use]
    pub fn sampled_extent_px(&self) -> Option<[f64; 4]> {
        let mut it = self.samples.iter();
        let first = it.next()?;
        let mut e = [first.x, first.y, first.x, first.y];
        for s in it {
            e = [e[0].min(s.x), e[1].min(s.y), e[2].max(s.x), e[3].max(s.y)];
        }
        Some(e)
    }

    /// N = min(N_f, N_a) over the settings that vary (1 for a single-setting session):
    /// β must stay below it.
    #[must_use]
    pub fn setting_resolution(&self) -> usize {
        let (f, a) = self.distinct_settings();
        match (f.len() > 1, a.len() > 1) {
            (true, true) => f.len().min(a.len()),
            (true, false) => f.len(),
            (false, true) => a.len(),
            (false, false) => 1,
        }
    }

    /// The distinct settings (f, a) of the session, merged by [`LensSetting::same_as`]
    /// (the first shot of each stands for it), sorted.
    #[must_use]
    pub fn distinct_setting_pairs(&self) -> Vec<LensSetting> {
        let mut out: Vec<LensSetting> = Vec::new();
        for s in &self.shots {
            let s = s.setting();
            if !out.iter().any(|o| o.same_as(s)) {
                out.push(s);
            }
        }
        out.sort_by(|a, b| {
            a.focal_mm
                .total_cmp(&b.focal_mm)
                .then(a.f_number.total_cmp(&b.f_number))
        });
        out
    }

    /// Checks β against the sampling of the settings: β < N = min(N_f, N_a) (the
    /// paper's constraint), and the settings shot must determine every term in f and
    /// a of order ≤ β — a 3 × 3 grid does for β = 2, three settings on a diagonal do
    /// not, and a least-squares fit would then invent the missing terms silently.
    ///
    /// # Errors
    /// [`ModelError::BetaTooLarge`] with the counts, [`ModelError::SettingsTooSparse`],
    /// or [`ModelError::OrderTooHigh`].
    pub fn check_beta(&self, beta: usize) -> Result<(), ModelError> {
        check_order(0, beta)?;
        let n = self.setting_resolution();
        if beta >= n {
            let (f, a) = self.distinct_settings();
            return Err(ModelError::BetaTooLarge {
                beta,
                need: beta + 1,
                n_f: f.len(),
                n_a: a.len(),
            });
        }
        let norm = self.normalisation();
        let basis = model_basis(&norm, 0, beta);
        let settings = self.distinct_setting_pairs();
        let mut a = DMatrix::zeros(settings.len(), basis.len());
        let mut row = vec![0.0; basis.len()];
        for (r, s) in settings.iter().enumerate() {
            let (nf, na) = norm.fa(*s);
            basis.row([0.0, 0.0, nf, na], &mut row);
            for (c, v) in row.iter().enumerate() {
                a[(r, c)] = *v;
            }
        }
        let sv = a.singular_values();
        let largest = sv.max();
        let rank = sv.iter().filter(|&&v| v > 1e-9 * largest).count();
        if rank < basis.len() {
            return Err(ModelError::SettingsTooSparse {
                beta,
                terms: basis.len(),
                settings: settings.len(),
            });
        }
        Ok(())
    }

    /// The width in pixels of the largest imaged square: per shot the 90th percentile
    /// of the spacing of neighbouring squares (from their chart row and column where
    /// known, else from nearest-neighbour distances), the largest over the shots.
    #[must_use]
    pub fn largest_square_px(&self) -> f64 {
        let mut best: f64 = 0.0;
        for shot in 0..self.shots.len() {
            let mine: Vec<&BlurSample> = self.samples.iter().filter(|s| s.shot == shot).collect();
            let mut widths = square_widths_from_grid(&mine);
            if widths.is_empty() {
                widths = nearest_neighbour_distances(&mine);
            }
            if widths.is_empty() {
                continue;
            }
            widths.sort_by(f64::total_cmp);
            best = best.max(widths[(widths.len() - 1) * 9 / 10]);
        }
        if best > 0.0 {
            best
        } else {
            self.width.max(self.height) as f64 / 10.0
        }
    }
}

/// Spacing of chart squares from samples with known (row, column): the distance to
/// each nearby square (up to two rows or columns away) divided by their offset in
/// squares, one value per pair.
fn square_widths_from_grid(samples: &[&BlurSample]) -> Vec<f64> {
    let mut by_square: std::collections::BTreeMap<[usize; 2], [f64; 2]> =
        std::collections::BTreeMap::new();
    for s in samples {
        if let Some(sq) = s.square {
            by_square.entry(sq).or_insert([s.x, s.y]);
        }
    }
    let mut out = Vec::new();
    for (&[r, c], p) in &by_square {
        for (dr, dc) in [(0usize, 1usize), (0, 2), (1, 0), (2, 0), (1, 1)] {
            if let Some(q) = by_square.get(&[r + dr, c + dc]) {
                out.push((p[0] - q[0]).hypot(p[1] - q[1]) / (dr as f64).hypot(dc as f64));
            }
        }
        // The other diagonal, which alternate-square sampling leaves as the only link.
        if c >= 1
            && let Some(q) = by_square.get(&[r + 1, c - 1])
        {
            out.push((p[0] - q[0]).hypot(p[1] - q[1]) / std::f64::consts::SQRT_2);
        }
    }
    out
}

/// Distance from each distinct sample position to its nearest neighbour.
fn nearest_neighbour_distances(samples: &[&BlurSample]) -> Vec<f64> {
    let mut pts: Vec<[f64; 2]> = samples.iter().map(|s| [s.x, s.y]).collect();
    pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup_by(|a, b| (a[0] - b[0]).abs() < 0.5 && (a[1] - b[1]).abs() < 0.5);
    if pts.len() < 2 {
        return Vec::new();
    }
    pts.iter()
        .enumerate()
        .map(|(i, p)| {
            pts.iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// Adds what `more` knows to `into`; a field both know differently is returned as
/// (name, known, other): a session's shots must come from one camera and lens unit.
fn merge_identity(
    into: &mut CameraIdentity,
    more: &CameraIdentity,
) -> Result<(), (&'static str, String, String)> {
    for (name, mine, theirs) in [
        ("make", &mut into.make, &more.make),
        ("model", &mut into.model, &more.model),
        ("body serial", &mut into.body_serial, &more.body_serial),
        ("lens", &mut into.lens_model, &more.lens_model),
        ("lens serial", &mut into.lens_serial, &more.lens_serial),
    ] {
        match (mine.as_ref(), theirs) {
            (Some(a), Some(b)) if a.trim() != b.trim() => {
                return Err((name, a.clone(), b.clone()));
            }
            (None, Some(b)) => *mine = Some(b.clone()),
            _ => {}
        }
    }
    Ok(())
}
