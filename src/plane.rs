//! Single-channel images of linear values, and the channel layout of a capture.
//!
//! Coordinates follow docs/formats.md: x right, y down, pixel centres at integers, (0, 0) the
//! centre of the top-left pixel. A [`ChannelPlane`] records where its pixels sit on the
//! full-resolution sensor, so every stage can report in sensor pixels.

use serde::{Deserialize, Serialize};

/// A value at or above this (white = 1) is clipped: the sensor or the file could not
/// hold the light there, so the pixel says only that the truth is at least this. Kernels
/// give it no weight and detection counts it against a square (one rule for both).
pub const CLIPPED_FROM: f64 = 0.995;

/// A row-major single-channel image of `f32` values (linear, normally in [0, 1]).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    #[must_use]
    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    #[must_use]
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// As [`Self::from_fn`], the rows made in parallel: for whole photos, where a
    /// serial pass over tens of millions of samples would keep every other core idle.
    #[must_use]
    pub fn par_from_fn(
        width: usize,
        height: usize,
        f: impl Fn(usize, usize) -> f32 + Sync,
    ) -> Self {
        use rayon::prelude::*;
        let mut data = vec![0.0; width * height];
        if width > 0 {
            data.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
                for (x, v) in row.iter_mut().enumerate() {
                    *v = f(x, y);
                }
            });
        }
        Self {
            width,
            height,
            data,
        }
    }

    #[inline]
    #[must_use]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: f32) {
        self.data[y * self.width + x] = v;
    }

    /// The value at integer coordinates, or `None` outside the plane.
    #[inline]
    #[must_use]
    pub fn get_checked(&self, x: i64, y: i64) -> Option<f32> {
        (x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height)
            .then(|| self.get(x as usize, y as usize))
    }

    /// Bilinear interpolation at a real position; `None` when any of the four
    /// neighbours lies outside the plane.
    #[must_use]
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f32> {
        let x0 = x.floor();
        let y0 = y.floor();
        let (ix, iy) = (x0 as i64, y0 as i64);
        if ix < 0 || iy < 0 || ix + 1 >= self.width as i64 || iy + 1 >= self.height as i64 {
            // Exactly on the last row/column is still inside.
            if ix >= 0
                && iy >= 0
                && (ix as usize) < self.width
                && (iy as usize) < self.height
                && x == x0
                && y == y0
            {
                return Some(self.get(ix as usize, iy as usize));
            }
            return None;
        }
        let fx = (x - x0) as f32;
        let fy = (y - y0) as f32;
        let (ix, iy) = (ix as usize, iy as usize);
        Some(bilinear_blend(
            [
                self.get(ix, iy),
                self.get(ix + 1, iy),
                self.get(ix, iy + 1),
                self.get(ix + 1, iy + 1),
            ],
            fx,
            fy,
        ))
    }

    /// The rectangle `[x0, x0 + w) × [y0, y0 + h)` read at every pixel moved by
    /// (dx, dy) px: sample (x, y) of the result is the plane at (x0 + x + dx, y0 + y +
    /// dy), interpolated with a Lanczos-3 window (sharp enough that a sub-pixel move
    /// does not itself blur what is compared). Positions past the border read the
    /// nearest edge pixel.
    #[must_use]
    pub fn shifted_crop(
        &self,
        (x0, y0): (usize, usize),
        (w, h): (usize, usize),
        [dx, dy]: [f64; 2],
    ) -> Plane {
        // Six taps per axis, normalised so a flat region stays flat.
        let taps = |d: f64| -> (isize, [f64; 6]) {
            let whole = d.floor();
            let frac = d - whole;
            let mut t = [0.0; 6];
            for (k, v) in t.iter_mut().enumerate() {
                *v = lanczos3(k as f64 - 2.0 - frac);
            }
            let sum: f64 = t.iter().sum();
            t.iter_mut().for_each(|v| *v /= sum);
            (whole as isize - 2, t)
        };
        let ((ox, tx), (oy, ty)) = (taps(dx), taps(dy));
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        Plane::from_fn(w, h, |x, y| {
            let mut acc = 0.0;
            for (b, wy) in ty.iter().enumerate() {
                let yy = clamp((y0 + y) as isize + oy + b as isize, self.height);
                for (a, wx) in tx.iter().enumerate() {
                    let xx = clamp((x0 + x) as isize + ox + a as isize, self.width);
                    acc += wx * wy * f64::from(self.get(xx, yy));
                }
            }
            acc as f32
        })
    }

    /// A copy of the rectangle `[x0, x0 + w) × [y0, y0 + h)`, which must lie inside.
    #[must_use]
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Plane {
        assert!(
            x0 + w <= self.width && y0 + h <= self.height,
            "crop outside the plane"
        );
        Plane::from_fn(w, h, |x, y| self.get(x0 + x, y0 + y))
    }

    #[must_use]
    pub fn mean(&self) -> f64 {
        if self.data.is_empty() {
            return 0.0;
        }
        self.data.iter().map(|&v| f64::from(v)).sum::<f64>() / self.data.len() as f64
    }
}

/// The colour channel a plane measures. G pools both green sites of a Bayer mosaic;
/// Y is a monochrome input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Channel {
    R,
    G,
    B,
    Y,
}

impl Channel {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Channel::R => "R",
            Channel::G => "G",
            Channel::B => "B",
            Channel::Y => "Y",
        }
    }
}

impl std::fmt::Display for Channel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Channel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "R" | "r" => Ok(Channel::R),
            "G" | "g" => Ok(Channel::G),
            "B" | "b" => Ok(Channel::B),
            "Y" | "y" => Ok(Channel::Y),
            other => Err(format!("unknown channel '{other}' (expected R, G, B or Y)")),
        }
    }
}

/// One plane of a capture and where its pixels sit on the sensor: plane pixel (i, j)
/// is at sensor `(step·i + offset_x, step·j + offset_y)`. A Bayer plane has step 2; an
/// RGB or monochrome image has step 1 and offset 0.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelPlane {
    pub channel: Channel,
    pub plane: Plane,
    pub step: usize,
    pub offset_x: usize,
    pub offset_y: usize,
}

impl ChannelPlane {
    /// Sensor position of plane pixel (i, j).
    #[inline]
    #[must_use]
    pub fn sensor_from_plane(&self, i: f64, j: f64) -> [f64; 2] {
        let s = self.step as f64;
        [s * i + self.offset_x as f64, s * j + self.offset_y as f64]
    }

    /// Plane position of a sensor point (may be fractional or outside).
    #[inline]
    #[must_use]
    pub fn plane_from_sensor(&self, x: f64, y: f64) -> [f64; 2] {
        let s = self.step as f64;
        [
            (x - self.offset_x as f64) / s,
            (y - self.offset_y as f64) / s,
        ]
    }
}

/// Focal length and aperture of a shot. `focal_mm` is the focal length in millimetres,
/// `f_number` the aperture as an f-number (N in f/N).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LensSetting {
    pub focal_mm: f64,
    pub f_number: f64,
}

impl LensSetting {
    /// How far apart two values of one setting may lie and still be the same setting:
    /// 0.1 % of the larger. EXIF stores rounded rationals and users type what the camera
    /// shows, so the same setting arrives as slightly different numbers, while settings
    /// a lens really distinguishes lie far further apart (a third of a stop is 12 % in
    /// f-number).
    pub const RELATIVE_TOLERANCE: f64 = 1e-3;

    /// Whether two focal lengths, or two f-numbers, are the same setting (within
    /// [`LensSetting::RELATIVE_TOLERANCE`]). The one rule every comparison of settings
    /// uses: grouping shots, matching a photo to measured kernels, sweeps.
    #[must_use]
    pub fn same_value(a: f64, b: f64) -> bool {
        (a - b).abs() <= Self::RELATIVE_TOLERANCE * a.abs().max(b.abs())
    }

    #[must_use]
    pub fn same_focal(self, other: LensSetting) -> bool {
        Self::same_value(self.focal_mm, other.focal_mm)
    }

    #[must_use]
    pub fn same_f_number(self, other: LensSetting) -> bool {
        Self::same_value(self.f_number, other.f_number)
    }

    /// The same focal length and the same f-number.
    #[must_use]
    pub fn same_as(self, other: LensSetting) -> bool {
        self.same_focal(other) && self.same_f_number(other)
    }

    /// The distinct values among `values` (focal lengths, or f-numbers), sorted; values
    /// that are the same setting are merged into the smallest of them.
    #[must_use]
    pub fn distinct_values(values: impl IntoIterator<Item = f64>) -> Vec<f64> {
        let mut v: Vec<f64> = values.into_iter().collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| Self::same_value(*a, *b));
        v
    }
}

/// "35 mm f/6.3": a setting as a photographer writes it (see [`focal_text`] and
/// [`f_number_text`]); every message names settings this way.
impl std::fmt::Display for LensSetting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {}",
            focal_text(self.focal_mm),
            f_number_text(self.f_number)
        )
    }
}

/// A focal length as a lens barrel writes it: whole millimetres ("35 mm"), a tenth
/// below 10 mm ("4.5 mm").
#[must_use]
pub fn focal_text(mm: f64) -> String {
    format!("{} mm", short_number(mm))
}

/// An f-number as a lens marks it: "f/2.8", "f/6.3", "f/10". A grid spaced in stops
/// holds f/6.32455…, and EXIF rationals give f/10.000000000000002; both read as the
/// camera shows them.
#[must_use]
pub fn f_number_text(n: f64) -> String {
    format!("f/{}", short_number(n))
}

/// A printed length in millimetres to a tenth, without a trailing ".0": "10.5",
/// "260".
#[must_use]
pub fn millimetres(v: f64) -> String {
    let text = format!("{v:.1}");
    text.strip_suffix(".0").map_or(text.clone(), str::to_string)
}

/// One decimal below 10, whole numbers from 10, never a trailing ".0".
#[must_use]
pub fn short_number(v: f64) -> String {
    if !v.is_finite() {
        return "unknown".into();
    }
    let text = if v.abs() < 9.95 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    };
    text.strip_suffix(".0").map_or(text.clone(), str::to_string)
}

/// Who made the shot: read from EXIF where present. Used to refuse a profile made
/// for another camera or lens unit.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CameraIdentity {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub make: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body_serial: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lens_model: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lens_serial: Option<String>,
}

/// What a RAW file says about its samples and its shot beyond the image and the
/// camera's identity: everything a RAW editor needs to develop the file again, kept so
/// a deblurred RAW can be written back as a DNG with it (`dng`).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct RawMeta {
    /// Colour (0 R, 1 G, 2 B) of the CFA sites at (x mod 2, y mod 2), in the order
    /// (0, 0), (1, 0), (0, 1), (1, 1).
    pub cfa: [u8; 4],
    /// Black level of each CFA site, same order.
    pub black: [u16; 4],
    pub white: u16,
    /// XYZ → camera RGB under [`RawMeta::calibration_illuminant`] (DNG ColorMatrix), when
    /// the file or the decoder's camera data has one.
    pub color_matrix: Option<[[f64; 3]; 3]>,
    /// EXIF LightSource code of the matrix (21: D65).
    pub calibration_illuminant: u16,
    /// The white balance as shot: camera RGB of a neutral, green 1 (DNG AsShotNeutral).
    pub as_shot_neutral: Option<[f64; 3]>,
    /// EXIF orientation, 1–8 (1: as stored).
    pub orientation: u16,
    pub exposure_s: Option<f64>,
    pub iso: Option<u32>,
    /// EXIF DateTimeOriginal, as written ("YYYY:MM:DD HH:MM:SS").
    pub date_time_original: Option<String>,
    pub lens_make: Option<String>,
    /// EXIF FocalLengthIn35mmFilm, mm: with the focal length, the camera's crop factor.
    pub focal_35mm: Option<f64>,
    /// EXIF LensSpecification: shortest and longest focal length (mm), widest
    /// aperture at each (f-number).
    pub lens_specification: Option<[f64; 4]>,
    /// The file's ImageDescription: for a DNG lensblur wrote, how it was made.
    pub description: Option<String>,
}

impl RawMeta {
    /// An RGGB mosaic with one black level, camera RGB taken as linear sRGB (the
    /// simulator's sensor) and a daylight white balance.
    #[must_use]
    pub fn rggb(black: u16, white: u16) -> Self {
        Self {
            cfa: [0, 1, 1, 2],
            black: [black; 4],
            white,
            // XYZ (D65) → linear sRGB.
            color_matrix: Some([
                [3.2406, -1.5372, -0.4986],
                [-0.9689, 1.8758, 0.0415],
                [0.0557, -0.2040, 1.0570],
            ]),
            calibration_illuminant: 21,
            as_shot_neutral: Some([0.82, 1.0, 0.74]),
            orientation: 1,
            exposure_s: None,
            iso: None,
            date_time_original: None,
            lens_make: None,
            focal_35mm: None,
            lens_specification: None,
            description: None,
        }
    }

    /// The CFA site index (0–3) of sensor pixel (x, y).
    #[must_use]
    pub fn site(x: usize, y: usize) -> usize {
        (y % 2) * 2 + x % 2
    }
}

impl CameraIdentity {
    /// Every field with its name, camera and lens type first, then the unit's serials.
    #[must_use]
    pub fn fields(&self) -> [(&'static str, Option<&str>); 5] {
        [
            ("make", self.make.as_deref()),
            ("model", self.model.as_deref()),
            ("lens", self.lens_model.as_deref()),
            ("body serial", self.body_serial.as_deref()),
            ("lens serial", self.lens_serial.as_deref()),
        ]
    }

    /// The one rule for two recorded values of a field being the same: equal once the
    /// padding some cameras write around them is trimmed.
    #[must_use]
    pub fn same_value(a: &str, b: &str) -> bool {
        a.trim() == b.trim()
    }

    /// What a person would call it, for messages: "Make Model, Lens (lens serial S)".
    #[must_use]
    pub fn describe(&self) -> String {
        let camera = [self.make.as_deref(), self.model.as_deref()]
            .into_iter()
            .flatten()
            .collect::<Vec<_>>()
            .join(" ");
        let mut parts = Vec::new();
        parts.push(if camera.is_empty() {
            "unknown camera".to_string()
        } else {
            camera
        });
        parts.push(
            self.lens_model
                .clone()
                .unwrap_or_else(|| "unknown lens".into()),
        );
        let mut out = parts.join(", ");
        for (name, v) in [
            ("body serial", &self.body_serial),
            ("lens serial", &self.lens_serial),
        ] {
            if let Some(v) = v {
                out.push_str(&format!(" ({name} {v})"));
            }
        }
        out
    }
}

/// What a shot or photo's pixels are, as far as blur goes: a profile measured on one
/// kind describes the blur of that kind only.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PictureKind {
    /// A RAW file's CFA planes: linear light, before any processing.
    Raw,
    /// A 16-bit or floating-point picture read as linear light (what `lensblur
    /// simulate` writes): the blur is the lens's, as in a RAW file.
    Linear,
    /// An 8-bit picture (a camera's or an editor's JPEG, an 8-bit PNG or TIFF): sRGB-
    /// decoded, but demosaiced, sharpened and tone-mapped in ways nobody recorded, which
    /// change the blur and add patterns of their own.
    Developed,
}

impl PictureKind {
    /// Whether a profile measured on `self` describes the blur of a photo of kind
    /// `photo`: RAW and linear pictures are both the lens's own blur in linear light.
    #[must_use]
    pub fn matches(self, photo: Self) -> bool {
        (self == Self::Developed) == (photo == Self::Developed)
    }

    /// One of this kind, for messages: "a RAW file", "a developed 8-bit picture".
    #[must_use]
    pub fn one(self) -> &'static str {
        match self {
            Self::Raw => "a RAW file",
            Self::Linear => "a linear 16-bit picture",
            Self::Developed => "a developed 8-bit picture",
        }
    }

    /// For messages, the kind in the plural.
    #[must_use]
    pub fn describe(self) -> &'static str {
        match self {
            Self::Raw => "RAW files (their CFA planes)",
            Self::Linear => "linear 16-bit pictures",
            Self::Developed => "developed 8-bit pictures (JPEG, or 8-bit PNG/TIFF)",
        }
    }
}

/// Whether `v` is one of the 256 values an 8-bit sample decodes to (sRGB or as it is),
/// to the last bit of the `f32` the loader made of it.
#[must_use]
pub fn is_eight_bit_level(v: f32) -> bool {
    let on = |decoded: f32| (decoded - v).abs() <= 1e-7 + 1e-6 * v.abs();
    let code = |e: f32| (e.clamp(0.0, 1.0) * 255.0).round() / 255.0;
    on(srgb_decode(code(srgb_encode(v.clamp(0.0, 1.0))))) || on(code(v))
}

/// A loaded shot: its channel planes in linear units (black 0, white 1), the sensor
/// size, and what is known of its settings and origin.
#[derive(Clone, Debug)]
pub struct Capture {
    pub width: usize,
    pub height: usize,
    pub planes: Vec<ChannelPlane>,
    /// From EXIF; `None` where the file did not say.
    pub setting_focal_mm: Option<f64>,
    pub setting_f_number: Option<f64>,
    /// Where the lens was focused, metres (infinite where the file says infinity),
    /// from EXIF SubjectDistance or the camera's own record; `None` where the file
    /// does not say. Blur changes with it: a profile knows the range it was measured at.
    pub setting_focus_m: Option<f64>,
    pub identity: CameraIdentity,
    /// True for a RAW (CFA) source.
    pub is_raw: bool,
    /// A RAW source's levels, colour and shot metadata; `None` for other images (and
    /// for shots made in memory).
    pub raw: Option<RawMeta>,
}

impl Capture {
    /// A capture of `planes` and nothing yet of its settings, its camera or (for a RAW
    /// file) its metadata: what decoding or a simulation leaves, before the loader
    /// fills in what the file says.
    #[must_use]
    pub fn of_planes(width: usize, height: usize, planes: Vec<ChannelPlane>, is_raw: bool) -> Self {
        Self {
            width,
            height,
            planes,
            setting_focal_mm: None,
            setting_f_number: None,
            setting_focus_m: None,
            identity: CameraIdentity::default(),
            is_raw,
            raw: None,
        }
    }

    /// The channels this capture reports, in R, G, B, Y order (G once however many
    /// green planes a mosaic has): the order a shot's kernels are listed in.
    #[must_use]
    pub fn channels(&self) -> Vec<Channel> {
        [Channel::R, Channel::G, Channel::B, Channel::Y]
            .into_iter()
            .filter(|&ch| self.planes.iter().any(|p| p.channel == ch))
            .collect()
    }

    /// What its pixels are: a RAW file's CFA planes, or a picture told apart by its
    /// values alone: one whose every sample (of up to 65 536 spread over each plane) is
    /// an 8-bit level is an 8-bit picture, whatever file it came from.
    #[must_use]
    pub fn picture_kind(&self) -> PictureKind {
        if self.is_raw {
            return PictureKind::Raw;
        }
        let eight_bit = self.planes.iter().all(|cp| {
            let data = &cp.plane.data;
            let stride = (data.len() / 65_536).max(1);
            data.iter().step_by(stride).all(|&v| is_eight_bit_level(v))
        });
        if eight_bit && !self.planes.is_empty() {
            PictureKind::Developed
        } else {
            PictureKind::Linear
        }
    }

    /// A full-resolution grey image for detection: an RGB/mono image's mean channel, or
    /// for a Bayer capture each pixel's own CFA value (the planes interleaved back), which
    /// keeps full resolution; the colour channels differ only in gain over a grey chart.
    #[must_use]
    pub fn grey(&self) -> Plane {
        let mut out = Plane::new(self.width, self.height);
        let mut count = vec![0u16; self.width * self.height];
        for cp in &self.planes {
            for j in 0..cp.plane.height {
                for i in 0..cp.plane.width {
                    let x = cp.step * i + cp.offset_x;
                    let y = cp.step * j + cp.offset_y;
                    if x < self.width && y < self.height {
                        out.data[y * self.width + x] += cp.plane.get(i, j);
                        count[y * self.width + x] += 1;
                    }
                }
            }
        }
        for (v, &c) in out.data.iter_mut().zip(&count) {
            if c > 1 {
                *v /= f32::from(c);
            }
        }
        out
    }
}

/// The Lanczos window of three lobes, sinc(t)·sinc(t/3) for |t| < 3.
fn lanczos3(t: f64) -> f64 {
    if t.abs() < 1e-12 {
        return 1.0;
    }
    if t.abs() >= 3.0 {
        return 0.0;
    }
    let p = std::f64::consts::PI * t;
    3.0 * p.sin() * (p / 3.0).sin() / (p * p)
}

/// The bilinear blend of four neighbouring samples `[(0, 0), (1, 0), (0, 1), (1, 1)]` at
/// fractions (`fx`, `fy`) between them: the one interpolation formula every bilinear
/// sampler in the crate uses ([`Plane::bilinear`], [`bilinear_zero_outside`]).
#[inline]
#[must_use]
pub fn bilinear_blend<T>(q: [T; 4], fx: T, fy: T) -> T
where
    T: Copy
        + From<f32>
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<Output = T>,
{
    let one = T::from(1.0);
    let [a, b, c, d] = q;
    (a * (one - fx) + b * fx) * (one - fy) + (c * (one - fx) + d * fx) * fy
}

/// An `n` × `n` row-major grid of samples between samples at (u, w) (in sample units),
/// zero outside the grid: how a kernel or a shape grid is read between its samples.
#[must_use]
pub fn bilinear_zero_outside(data: &[f64], n: usize, u: f64, w: f64) -> f64 {
    let (u0, w0) = (u.floor(), w.floor());
    let get = |i: f64, j: f64| -> f64 {
        if i < 0.0 || j < 0.0 || i >= n as f64 || j >= n as f64 {
            0.0
        } else {
            data[j as usize * n + i as usize]
        }
    };
    bilinear_blend(
        [
            get(u0, w0),
            get(u0 + 1.0, w0),
            get(u0, w0 + 1.0),
            get(u0 + 1.0, w0 + 1.0),
        ],
        u - u0,
        w - w0,
    )
}

/// The sRGB transfer function's decoding: an encoded value in [0, 1] to linear light.
#[must_use]
pub fn srgb_decode(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB transfer function's encoding: linear light in [0, 1] (callers clamp) to
/// its encoded value.
#[must_use]
pub fn srgb_encode(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Half-sample symmetric reflection of the index `i` into `[0, n)`, repeated as needed
/// (… 1 0 | 0 1 … n−1 | n−1 n−2 …): how filters and tiles read past an image's border.
#[inline]
#[must_use]
pub fn reflect(i: isize, n: usize) -> usize {
    let n2 = 2 * n as isize;
    let m = i.rem_euclid(n2);
    if m >= n as isize {
        (n2 - 1 - m) as usize
    } else {
        m as usize
    }
}

/// `n` values from `lo` to `hi`, evenly spaced (geometrically when `log`).
#[must_use]
pub fn spaced(lo: f64, hi: f64, n: usize, log: bool) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let t = if n > 1 {
                i as f64 / (n - 1) as f64
            } else {
                0.5
            };
            if log {
                (lo.ln() + t * (hi.ln() - lo.ln())).exp()
            } else {
                lo + t * (hi - lo)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_read_as_a_camera_shows_them() {
        let s = LensSetting {
            focal_mm: 35.0,
            f_number: 40f64.sqrt(),
        };
        assert_eq!(s.to_string(), "35 mm f/6.3");
        assert_eq!(f_number_text(10.000_000_000_000_002), "f/10");
        assert_eq!(f_number_text(2.8), "f/2.8");
        assert_eq!(f_number_text(4.0), "f/4");
        assert_eq!(focal_text(4.5), "4.5 mm");
        assert_eq!(focal_text(104.6), "105 mm");
    }

    #[test]
    fn bilinear_reproduces_a_plane() {
        let p = Plane::from_fn(5, 4, |x, y| 2.0 * x as f32 + 3.0 * y as f32);
        let v = p.bilinear(1.25, 2.5).unwrap();
        assert!((v - (2.5 + 7.5)).abs() < 1e-5);
        assert!(p.bilinear(4.0, 3.0).is_some());
        assert!(p.bilinear(4.5, 1.0).is_none());
        assert!(p.bilinear(-0.1, 1.0).is_none());
    }

    #[test]
    fn plane_sensor_round_trip() {
        let cp = ChannelPlane {
            channel: Channel::B,
            plane: Plane::new(2, 2),
            step: 2,
            offset_x: 1,
            offset_y: 1,
        };
        let [x, y] = cp.sensor_from_plane(3.0, 4.0);
        assert_eq!([x, y], [7.0, 9.0]);
        assert_eq!(cp.plane_from_sensor(x, y), [3.0, 4.0]);
    }

    #[test]
    fn reflection() {
        assert_eq!(reflect(-1, 5), 0);
        assert_eq!(reflect(5, 5), 4);
        // Half-sample symmetric: … 3 4 4 3 2 1 0 | 0 1 2 3 4 | 4 3 …
        assert_eq!(reflect(-7, 5), 3);
        assert_eq!(reflect(12, 5), 2);
    }
}
