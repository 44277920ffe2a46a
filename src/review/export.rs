//! Export: a plot's data as CSV, and a plot cut out of a screenshot as PNG (a deblurred
//! photo is written whole by [`crate::deblur::output::deblur_and_write`]).

use std::path::Path;

/// A plot's data as the studio draws it, for saving beside its picture: the axes'
/// titles and every named series of (x, y) points.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotTable {
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<(String, Vec<[f64; 2]>)>,
}

/// A CSV field, quoted when it holds a comma, a quote or a line break (axis titles
/// such as "σ, px" do).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// The table as CSV: a header `series,<x axis>,<y axis>`, then one row per point.
/// Points with a non-finite coordinate are not drawn, so they are left out here too.
#[must_use]
pub fn plot_csv(table: &PlotTable) -> String {
    let mut out = format!(
        "series,{},{}\n",
        csv_field(&table.x_label),
        csv_field(&table.y_label)
    );
    for (name, points) in &table.series {
        let name = csv_field(name);
        for [x, y] in points
            .iter()
            .filter(|p| p[0].is_finite() && p[1].is_finite())
        {
            out.push_str(&format!("{name},{x},{y}\n"));
        }
    }
    out
}

/// Writes a rectangle `[x0, y0, x1, y1]` (pixels, clamped to the image) of an RGBA
/// image `width` × `height` as a PNG, atomically: a plot cut out of a window's
/// screenshot.
pub fn write_png_crop(
    path: &Path,
    rgba: Vec<u8>,
    width: usize,
    height: usize,
    rect: [usize; 4],
) -> Result<(), String> {
    let to_u32 =
        |v: usize| u32::try_from(v).map_err(|_| format!("an image {v} px wide is too large"));
    let img = image::RgbaImage::from_raw(to_u32(width)?, to_u32(height)?, rgba)
        .ok_or_else(|| format!("the screenshot's pixels do not fill {width} × {height}"))?;
    let (x0, y0) = (rect[0].min(width), rect[1].min(height));
    let (x1, y1) = (rect[2].clamp(x0, width), rect[3].clamp(y0, height));
    if x1 == x0 || y1 == y0 {
        return Err("the plot is not on screen".into());
    }
    let crop = image::imageops::crop_imm(
        &img,
        to_u32(x0)?,
        to_u32(y0)?,
        to_u32(x1 - x0)?,
        to_u32(y1 - y0)?,
    )
    .to_image();
    let mut bytes = Vec::new();
    crop.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| format!("cannot encode the PNG: {e}"))?;
    crate::io::write_atomic(path, &bytes).map_err(|e| e.to_string())
}
