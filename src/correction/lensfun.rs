//! lensfun's lens database entry (`lensdatabase version="1"`, the format darktable,
//! RawTherapee, digiKam, Hugin and GIMP read), and the rules for a right one. The one
//! owner of that format (docs/formats.md, "lensfun entry"); the coordinate conventions
//! its coefficients are in are [`super::frame`]'s.

use super::{DistortionModel, LensCorrection, TcaModel};
use std::fmt::Write as _;

/// Who the entry is for: the camera and lens as the shots' EXIF names them (lensfun
/// finds them by those names), and what lensfun needs beyond the calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct LensfunNames {
    pub camera_maker: String,
    pub camera_model: String,
    pub lens_maker: String,
    pub lens_model: String,
    /// lensfun finds a lens only on a camera of the same (or a compatible) mount.
    pub mount: String,
    /// The camera's crop factor (35 mm diagonal over the sensor's).
    pub crop_factor: f64,
    /// The lens's focal range, mm (equal ends for a prime).
    pub focal_range_mm: [f64; 2],
    /// The lens's widest aperture (smallest f-number) over its range, where known.
    pub max_aperture: Option<f64>,
}

/// What the user says where the shots' EXIF is silent or wrong.
#[derive(Clone, Debug, Default)]
pub struct NameOverrides {
    pub camera_maker: Option<String>,
    pub camera_model: Option<String>,
    pub lens_maker: Option<String>,
    pub lens_model: Option<String>,
    pub mount: Option<String>,
    pub crop_factor: Option<f64>,
    pub focal_range_mm: Option<[f64; 2]>,
}

/// Why an entry cannot be written: each says what to do instead.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EntryError {
    #[error("the shots' EXIF names no {0}: pass {1} with the name your editor shows for it")]
    MissingName(&'static str, &'static str),
    #[error(
        "the camera's crop factor is unknown (no 35 mm focal length in EXIF): pass --crop-factor (1 for full frame, 1.5 or 1.6 for APS-C, 2 for Four Thirds)"
    )]
    MissingCropFactor,
    #[error(
        "every shot is at {focal} mm but the lens {range}: lensfun would apply {focal} mm's distortion at every focal length. Shoot the chart at several focal lengths (at least both ends), or pass --focal-range {focal} if the lens is a {focal} mm prime"
    )]
    OneFocalLength { focal: String, range: String },
    #[error(
        "the light on the chart was not even at {settings}: a gradient of {stops:.2} stops across it that no lens fall-off explains (more than {limit} stops), so the fall-off cannot be told from the light. Light the chart evenly (two lamps at 45°, or overcast daylight) and shoot again, or pass --no-vignetting to write distortion and lateral colour only"
    )]
    UnevenLight {
        settings: String,
        stops: f64,
        limit: f64,
    },
}

impl LensfunNames {
    /// The names from the shots' EXIF (`exif`, any one shot's: a session is one
    /// camera and lens) and the user's overrides, and the focal lengths `focals` the
    /// shots cover.
    ///
    /// # Errors
    /// A missing name or crop factor; a zoom measured at one focal length only.
    pub fn resolve(
        exif: &crate::raw::ExifInfo,
        overrides: &NameOverrides,
        focals: &[f64],
    ) -> Result<Self, EntryError> {
        let pick = |given: &Option<String>, found: Option<&String>| {
            given
                .clone()
                .or_else(|| found.cloned())
                .filter(|s| !s.trim().is_empty())
        };
        let id = &exif.identity;
        let camera_maker = pick(&overrides.camera_maker, id.make.as_ref())
            .ok_or(EntryError::MissingName("camera maker", "--camera-maker"))?;
        let camera_model = pick(&overrides.camera_model, id.model.as_ref())
            .ok_or(EntryError::MissingName("camera model", "--camera-model"))?;
        let lens_model = pick(&overrides.lens_model, id.lens_model.as_ref())
            .ok_or(EntryError::MissingName("lens", "--lens-model"))?;
        // Cameras rarely record the lens's maker; the camera's is the usual guess.
        let lens_maker = pick(&overrides.lens_maker, exif.lens_make.as_ref())
            .unwrap_or_else(|| camera_maker.clone());
        let crop_factor = overrides
            .crop_factor
            .or_else(|| Some(exif.focal_35mm? / exif.focal_mm?))
            .filter(|c| c.is_finite() && *c > 0.1 && *c < 20.0)
            .ok_or(EntryError::MissingCropFactor)?;
        let spec = exif.lens_specification;
        let focal_range_mm = overrides
            .focal_range_mm
            .or_else(|| spec.map(|s| [s[0], s[1]]))
            .filter(|r| r[0] > 0.0 && r[1] >= r[0]);
        let (lo, hi) = focals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &f| {
                (a.min(f), b.max(f))
            });
        let distinct = crate::plane::LensSetting::distinct_values(focals.iter().copied());
        let focal_range_mm = match focal_range_mm {
            Some(r)
                if distinct.len() == 1 && !crate::plane::LensSetting::same_value(r[0], r[1]) =>
            {
                return Err(EntryError::OneFocalLength {
                    focal: num(lo),
                    range: format!("zooms {}–{} mm", num(r[0]), num(r[1])),
                });
            }
            Some(r) => r,
            None if distinct.len() == 1 => {
                return Err(EntryError::OneFocalLength {
                    focal: num(lo),
                    range: "does not say its focal range (no EXIF LensSpecification)".into(),
                });
            }
            None => [lo, hi],
        };
        let mount = overrides
            .mount
            .clone()
            .filter(|s| !s.trim().is_empty())
            .unwrap_or_else(|| format!("{camera_maker} {camera_model}"));
        Ok(Self {
            camera_maker,
            camera_model,
            lens_maker,
            lens_model,
            mount,
            crop_factor,
            focal_range_mm,
            max_aperture: spec.map(|s| s[2]).filter(|a| *a > 0.0),
        })
    }
}

/// The entry's XML, or why it would be a wrong file: light too uneven to measure the
/// fall-off, unless `skip_vignetting` leaves it out.
///
/// # Errors
/// [`EntryError::UnevenLight`] naming the worst setting.
pub fn checked_entry(
    names: &LensfunNames,
    correction: &LensCorrection,
    skip_vignetting: bool,
    provenance: &str,
) -> Result<String, EntryError> {
    let mut correction = correction.clone();
    if skip_vignetting {
        correction.vignetting.clear();
    } else if let Some(worst) = correction
        .uneven_light()
        .max_by(|a, b| a.gradient_stops.total_cmp(&b.gradient_stops))
    {
        let settings: Vec<String> = correction
            .uneven_light()
            .map(|v| {
                format!(
                    "{} mm f/{}",
                    num(v.setting.focal_mm),
                    num(v.setting.f_number)
                )
            })
            .collect();
        return Err(EntryError::UnevenLight {
            settings: settings.join(", "),
            stops: worst.gradient_stops,
            limit: super::UNEVEN_LIGHT_STOPS,
        });
    }
    Ok(entry_xml(names, &correction, provenance))
}

/// The subject distance written with each vignetting entry, m: chart sessions rarely
/// record it, and lensfun weighs distance by 0.1 / d, so a far distance keeps an
/// entry equally close to any query beyond a metre.
pub const VIGNETTING_DISTANCE_M: f64 = 1000.0;

/// The entry as lensfun's XML (database version 1, which lensfun 0.3 and later read).
#[must_use]
pub fn entry_xml(names: &LensfunNames, correction: &LensCorrection, provenance: &str) -> String {
    let mut x = String::new();
    let e = escape;
    let _ = writeln!(x, "<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
    let _ = writeln!(x, "<!-- {} -->", comment(provenance));
    let _ = writeln!(x, "<lensdatabase version=\"1\">");
    let _ = writeln!(x, "    <camera>");
    let _ = writeln!(x, "        <maker>{}</maker>", e(&names.camera_maker));
    let _ = writeln!(x, "        <model>{}</model>", e(&names.camera_model));
    let _ = writeln!(x, "        <mount>{}</mount>", e(&names.mount));
    let _ = writeln!(
        x,
        "        <cropfactor>{}</cropfactor>",
        num(names.crop_factor)
    );
    let _ = writeln!(x, "    </camera>");
    let _ = writeln!(x, "    <lens>");
    let _ = writeln!(x, "        <maker>{}</maker>", e(&names.lens_maker));
    let _ = writeln!(x, "        <model>{}</model>", e(&names.lens_model));
    let _ = writeln!(x, "        <mount>{}</mount>", e(&names.mount));
    let [f0, f1] = names.focal_range_mm;
    if (f1 - f0).abs() < 1e-9 {
        let _ = writeln!(x, "        <focal value=\"{}\"/>", num(f0));
    } else {
        let _ = writeln!(
            x,
            "        <focal min=\"{}\" max=\"{}\"/>",
            num(f0),
            num(f1)
        );
    }
    if let Some(a) = names.max_aperture {
        let _ = writeln!(x, "        <aperture min=\"{}\"/>", num(a));
    }
    let _ = writeln!(x, "        <type>rectilinear</type>");
    let _ = writeln!(
        x,
        "        <cropfactor>{}</cropfactor>",
        num(names.crop_factor)
    );
    let _ = writeln!(
        x,
        "        <aspect-ratio>{}</aspect-ratio>",
        num(correction.frame.entry_aspect)
    );
    let _ = writeln!(x, "        <calibration>");
    // lensfun's DTD orders the calibration's children: distortion, then tca, then
    // vignetting.
    for f in &correction.focal {
        let d = f.distortion_fit(correction.distortion_model);
        let terms = match d.model {
            DistortionModel::Poly3 => format!("k1=\"{}\"", coef(d.coefficients[0])),
            DistortionModel::Poly5 => format!(
                "k1=\"{}\" k2=\"{}\"",
                coef(d.coefficients[0]),
                coef(d.coefficients[1])
            ),
            DistortionModel::PtLens => format!(
                "a=\"{}\" b=\"{}\" c=\"{}\"",
                coef(d.coefficients[0]),
                coef(d.coefficients[1]),
                coef(d.coefficients[2])
            ),
        };
        let _ = writeln!(
            x,
            "            <distortion model=\"{}\" focal=\"{}\" {terms}/>",
            d.model.name(),
            num(f.focal_mm)
        );
    }
    for f in &correction.focal {
        let Some(t) = f.tca_fit(correction.tca_model) else {
            continue;
        };
        let terms = match t.model {
            TcaModel::Linear => format!(
                "kr=\"{}\" kb=\"{}\"",
                coef(t.red.terms[0]),
                coef(t.blue.terms[0])
            ),
            TcaModel::Poly3 => format!(
                "vr=\"{}\" vb=\"{}\" cr=\"{}\" cb=\"{}\" br=\"{}\" bb=\"{}\"",
                coef(t.red.terms[0]),
                coef(t.blue.terms[0]),
                coef(t.red.terms[1]),
                coef(t.blue.terms[1]),
                coef(t.red.terms[2]),
                coef(t.blue.terms[2])
            ),
        };
        let _ = writeln!(
            x,
            "            <tca model=\"{}\" focal=\"{}\" {terms}/>",
            t.model.name(),
            num(f.focal_mm)
        );
    }
    for v in &correction.vignetting {
        let [k1, k2, k3] = v.k;
        let _ = writeln!(
            x,
            "            <vignetting model=\"pa\" focal=\"{}\" aperture=\"{}\" distance=\"{}\" k1=\"{}\" k2=\"{}\" k3=\"{}\"/>",
            num(v.setting.focal_mm),
            num(v.setting.f_number),
            num(VIGNETTING_DISTANCE_M),
            coef(k1),
            coef(k2),
            coef(k3)
        );
    }
    let _ = writeln!(x, "        </calibration>");
    let _ = writeln!(x, "    </lens>");
    let _ = writeln!(x, "</lensdatabase>");
    x
}

/// A setting or size as lensfun's attributes take it: a plain decimal, no exponent.
fn num(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.into()
    }
}

/// A coefficient: plain decimal (the DTD's NMTOKEN allows no spaces; lensfun parses
/// with `atof`), enough digits for 1e-6 relative.
fn coef(v: f64) -> String {
    let s = format!("{v:.9}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" || s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// Text safe inside an XML comment (no "--").
fn comment(s: &str) -> String {
    escape(s).replace("--", "- -")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_plain_decimals() {
        assert_eq!(num(24.0), "24");
        assert_eq!(num(1.5), "1.5");
        assert_eq!(coef(-0.000_012_345_678_9), "-0.000012346");
        assert_eq!(coef(1e-12), "0");
        assert_eq!(escape("A&B <\"x\">"), "A&amp;B &lt;&quot;x&quot;&gt;");
        assert_eq!(comment("a -- b"), "a - - b");
    }
}
