//! What lensblur takes from a file's EXIF, and how that joins what the RAW decoder read.

use super::DecodedMeta;
use crate::plane::Capture;

/// What lensblur takes from a file's EXIF.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExifInfo {
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
    pub identity: crate::plane::CameraIdentity,
    pub exposure_s: Option<f64>,
    pub iso: Option<u32>,
    pub date_time_original: Option<String>,
    pub lens_make: Option<String>,
    pub description: Option<String>,
    /// FocalLengthIn35mmFilm, mm.
    pub focal_35mm: Option<f64>,
    /// LensSpecification: shortest and longest focal length, widest aperture at each.
    pub lens_specification: Option<[f64; 4]>,
    /// SubjectDistance, metres: where the camera focused (infinite where it says
    /// infinity). Blur depends on it; a profile knows the range it was measured at.
    pub subject_distance_m: Option<f64>,
}

impl ExifInfo {
    /// Takes what the RAW decoder read where EXIF (as we parse it) has nothing: CR3
    /// keeps its EXIF where a TIFF reader does not look, and lens names come from
    /// maker notes.
    pub(super) fn take_decoded(&mut self, meta: &DecodedMeta) {
        self.focal_mm = self.focal_mm.or(meta.focal_mm);
        self.f_number = self.f_number.or(meta.f_number);
        self.subject_distance_m = self.subject_distance_m.or(meta.subject_distance_m);
        let lens = &mut self.identity.lens_model;
        *lens = lens.take().or_else(|| meta.lens_model.clone());
    }

    /// Fills what the capture does not already have (settings) or has less exactly
    /// (EXIF's make and model win over the RAW decoder's cleaned names).
    pub(super) fn fill(self, capture: &mut Capture) {
        capture.setting_focal_mm = capture.setting_focal_mm.or(self.focal_mm);
        capture.setting_f_number = capture.setting_f_number.or(self.f_number);
        capture.setting_focus_m = capture.setting_focus_m.or(self.subject_distance_m);
        let id = &mut capture.identity;
        id.make = self.identity.make.or(id.make.take());
        id.model = self.identity.model.or(id.model.take());
        id.body_serial = self.identity.body_serial.or(id.body_serial.take());
        id.lens_model = self.identity.lens_model.or(id.lens_model.take());
        id.lens_serial = self.identity.lens_serial.or(id.lens_serial.take());
        if let Some(raw) = &mut capture.raw {
            raw.exposure_s = self.exposure_s;
            raw.iso = self.iso;
            raw.date_time_original = self.date_time_original;
            raw.lens_make = self.lens_make;
            raw.focal_35mm = self.focal_35mm;
            raw.lens_specification = self.lens_specification;
            raw.description = self.description;
        }
    }
}

/// Focal length, f-number and identity from a file's EXIF, by tag number: DNGs often
/// keep these in IFD0, where they are not the EXIF-context tags a lookup by name
/// expects. A file without EXIF, or with EXIF we cannot parse, has none.
#[must_use]
pub fn read_exif(bytes: &[u8]) -> ExifInfo {
    let mut info = ExifInfo::default();
    let Ok(exif) = exif::Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)) else {
        return info;
    };
    for f in exif.fields() {
        let number = f.tag.number();
        let rational = match &f.value {
            exif::Value::Rational(v) => v
                .first()
                .map(|r| f64::from(r.num) / f64::from(r.denom.max(1))),
            exif::Value::Short(v) => v.first().map(|&x| f64::from(x)),
            exif::Value::Long(v) => v.first().map(|&x| f64::from(x)),
            _ => None,
        }
        .filter(|v| v.is_finite() && *v > 0.0);
        let text = match &f.value {
            exif::Value::Ascii(v) => v
                .first()
                .map(|s| {
                    String::from_utf8_lossy(s)
                        .trim_end_matches('\0')
                        .trim()
                        .chars()
                        .take(256)
                        .collect::<String>()
                })
                .filter(|s| !s.is_empty()),
            _ => None,
        };
        let id = &mut info.identity;
        match number {
            37386 => info.focal_mm = info.focal_mm.or(rational),
            37382 => {
                // SubjectDistance: 0xFFFFFFFF is infinity, 0 unknown.
                if let exif::Value::Rational(v) = &f.value
                    && let Some(r) = v.first()
                {
                    info.subject_distance_m = info.subject_distance_m.or(if r.num == u32::MAX {
                        Some(f64::INFINITY)
                    } else {
                        rational
                    });
                }
            }
            33434 => info.exposure_s = info.exposure_s.or(rational),
            // ISOSpeedRatings; PhotographicSensitivity in EXIF 2.3.
            34855 => info.iso = info.iso.or(rational.map(|v| v.round() as u32)),
            36867 => info.date_time_original = info.date_time_original.take().or(text),
            42035 => info.lens_make = info.lens_make.take().or(text),
            41989 => info.focal_35mm = info.focal_35mm.or(rational),
            42034 => {
                if let exif::Value::Rational(v) = &f.value
                    && v.len() == 4
                {
                    let spec: Vec<f64> = v
                        .iter()
                        .map(|r| f64::from(r.num) / f64::from(r.denom.max(1)))
                        .collect();
                    // Unknown values are written as 0/0: keep the focal range anyway.
                    if spec[0].is_finite() && spec[1].is_finite() && spec[0] > 0.0 {
                        info.lens_specification = Some([spec[0], spec[1], spec[2], spec[3]]);
                    }
                }
            }
            270 => info.description = info.description.take().or(text),
            33437 => info.f_number = info.f_number.or(rational),
            271 => id.make = id.make.take().or(text),
            272 => id.model = id.model.take().or(text),
            42033 => id.body_serial = id.body_serial.take().or(text),
            42036 => id.lens_model = id.lens_model.take().or(text),
            42037 => id.lens_serial = id.lens_serial.take().or(text),
            _ => {}
        }
    }
    info
}
