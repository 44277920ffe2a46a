//! Developing a RAW capture for people to look at, through imagepipe: demosaic, white
//! balance, the camera's colour matrix to sRGB, a base tone curve and the sRGB gamma —
//! what a RAW editor shows before any edit. Display only: the tone curve and the
//! matrix make these pixels useless for measuring blur, which always reads the linear
//! CFA planes.
//!
//! The capture's own planes go in (through the mosaic they came from, [`crate::dng::mosaic`]),
//! not the file: so a deblurred capture, still in memory, develops exactly as its
//! original does, and files rawloader refuses (the uncompressed tiled DNGs we read
//! ourselves) develop too.

use crate::plane::{Capture, RawMeta};

/// An 8-bit sRGB image, row-major RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Developed {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

#[derive(Debug, thiserror::Error)]
pub enum DevelopError {
    #[error("not a RAW capture with its metadata (only RAW files are developed)")]
    NotRaw,
    #[error("the RAW developer failed: {0}")]
    Failed(String),
}

/// How the developed image is turned.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Orient {
    /// As the sensor recorded it, pixel for pixel: what overlays in sensor coordinates
    /// (detected squares, regions) are drawn on.
    #[default]
    Sensor,
    /// As the camera held it (EXIF orientation applied): for exported previews.
    AsShot,
}

/// Develops a RAW capture, scaled down to fit `max_side` pixels when given.
///
/// # Errors
/// The capture is not a Bayer RAW with its metadata, or imagepipe fails on it.
pub fn develop(
    capture: &Capture,
    max_side: Option<usize>,
    orient: Orient,
) -> Result<Developed, DevelopError> {
    let meta = capture.raw.as_ref().ok_or(DevelopError::NotRaw)?;
    let mosaic = crate::dng::mosaic(capture).ok_or(DevelopError::NotRaw)?;
    let image = raw_image(capture, meta, mosaic, orient);
    // imagepipe's ops index slices by the image size they were given; a malformed
    // capture must cost a message, not the program.
    let out = std::panic::catch_unwind(move || {
        let mut pipeline =
            imagepipe::Pipeline::new_from_source(imagepipe::ImageSource::Raw(image))?;
        if let Some(side) = max_side {
            pipeline.globals.settings.maxwidth = side;
            pipeline.globals.settings.maxheight = side;
        }
        pipeline.output_8bit(None)
    })
    .map_err(|_| DevelopError::Failed("it stopped on this image".into()))?
    .map_err(DevelopError::Failed)?;
    if out.data.len() != out.width * out.height * 3 {
        return Err(DevelopError::Failed("it returned a malformed image".into()));
    }
    Ok(Developed {
        width: out.width,
        height: out.height,
        rgb: out.data,
    })
}

/// The rawloader image imagepipe develops: our mosaic with the file's levels, CFA,
/// white balance and colour matrix.
fn raw_image(
    capture: &Capture,
    meta: &RawMeta,
    mosaic: Vec<u16>,
    orient: Orient,
) -> rawloader::RawImage {
    let letters = ['R', 'G', 'B'];
    let pattern: String = meta
        .cfa
        .iter()
        .map(|&c| letters.get(usize::from(c)).copied().unwrap_or('G'))
        .collect();
    // rawloader keeps one black level per colour; where a colour's sites differ, the
    // first site of that colour speaks for it.
    let mut blacklevels = [0u16; 4];
    for site in (0..4).rev() {
        blacklevels[usize::from(meta.cfa[site]).min(3)] = meta.black[site];
    }
    let mut xyz_to_cam = [[0.0f32; 3]; 4];
    // Without a matrix, camera RGB is taken as sRGB (what the simulator's sensor is).
    let m = meta
        .color_matrix
        .unwrap_or_else(|| RawMeta::rggb(0, 1).color_matrix.unwrap_or_default());
    for (row, src) in xyz_to_cam.iter_mut().zip(m.iter()) {
        for (o, &v) in row.iter_mut().zip(src) {
            *o = v as f32;
        }
    }
    // imagepipe scales each row of the matrix to sum to one, which puts a white-balanced
    // camera white at XYZ (1, 1, 1), and then takes Lab relative to D65: every neutral
    // would come out pink. So the multipliers we hand it take the as-shot neutral to the
    // camera response of D65 under that scaled matrix, not to (1, 1, 1): white paper
    // develops white. NaN marks the fourth colour a 3-colour sensor lacks, as
    // rawloader's DNG decoder does; without a neutral imagepipe balances for daylight.
    let d65 = [0.950_47, 1.0, 1.088_83];
    let d65_camera: [f64; 3] = std::array::from_fn(|r| {
        let sum: f64 = m[r].iter().sum();
        let row = m[r].iter().zip(&d65).map(|(a, b)| a * b).sum::<f64>();
        if sum.abs() > 1e-9 { row / sum } else { 1.0 }
    });
    let wb_coeffs = meta.as_shot_neutral.map_or([f32::NAN; 4], |n| {
        [
            (d65_camera[0] / n[0]) as f32,
            (d65_camera[1] / n[1]) as f32,
            (d65_camera[2] / n[2]) as f32,
            f32::NAN,
        ]
    });
    let orientation = match orient {
        Orient::Sensor => rawloader::Orientation::Normal,
        Orient::AsShot => rawloader::Orientation::from_u16(meta.orientation),
    };
    let make = capture.identity.make.clone().unwrap_or_default();
    let model = capture.identity.model.clone().unwrap_or_default();
    rawloader::RawImage {
        clean_make: make.clone(),
        clean_model: model.clone(),
        make,
        model,
        width: capture.width,
        height: capture.height,
        cpp: 1,
        wb_coeffs,
        whitelevels: [meta.white; 4],
        blacklevels,
        xyz_to_cam,
        cfa: rawloader::CFA::new(&pattern),
        crops: [0; 4],
        blackareas: Vec::new(),
        orientation,
        data: rawloader::RawImageData::Integer(mosaic),
    }
}

/// Encodes a developed image as an 8-bit sRGB PNG (written atomically).
///
/// # Errors
/// Encoding or writing fails.
pub fn save_png(path: &std::path::Path, image: &Developed) -> Result<(), crate::raw::SaveError> {
    let err = |reason: String| crate::raw::SaveError {
        path: path.to_path_buf(),
        reason,
    };
    let (w, h) = (
        u32::try_from(image.width).map_err(|_| err("too wide".into()))?,
        u32::try_from(image.height).map_err(|_| err("too tall".into()))?,
    );
    let buffer = image::RgbImage::from_raw(w, h, image.rgb.clone())
        .ok_or_else(|| err("image buffer size".into()))?;
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(buffer)
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| err(e.to_string()))?;
    crate::io::write_atomic(path, &bytes).map_err(|e| err(e.source.to_string()))
}
