//! The chart for printing: SVG and PDF at its physical size (vector, exact circles),
//! PNG at a chosen resolution through the exact rasteriser.

use super::{ChartSpec, rasterize};
use crate::geometry::Homography;
use crate::plane::Plane;

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("invalid chart: {0}")]
    Invalid(String),
    #[error("{0}")]
    TooLarge(String),
}

const PT_PER_MM: f64 = 72.0 / 25.4;
/// Largest PNG we write, in pixels: past this a DPI was mistyped.
const MAX_PNG_PIXELS: f64 = 400e6;

/// A circle's centre in chart units and whether it is black.
type Circle = ([f64; 2], bool);

/// The black shapes of the chart in chart units: squares (column, row), and the circles
/// with their colour (black inside white squares; white circles inside black squares
/// are drawn over the squares in white).
fn shapes(spec: &ChartSpec) -> (Vec<(usize, usize)>, Vec<Circle>) {
    let mut squares = Vec::new();
    let mut circles = Vec::new();
    for row in 0..spec.rows {
        for col in 0..spec.cols {
            let black = spec.is_black(col, row);
            if black {
                squares.push((col, row));
            }
            for c in &spec.circle_centres {
                circles.push(([col as f64 + c[0], row as f64 + c[1]], !black));
            }
        }
    }
    (squares, circles)
}

/// SVG at the chart's physical size (`square_mm` per square), in millimetres.
///
/// # Errors
/// An invalid spec.
pub fn to_svg(spec: &ChartSpec) -> Result<String, ExportError> {
    use svg::Document;
    use svg::node::element::{Circle, Rectangle};
    spec.validate()
        .map_err(|e| ExportError::Invalid(e.to_string()))?;
    let s = spec.square_mm;
    let m = spec.margin;
    let (w_mm, h_mm) = spec.paper_mm();
    let mm = |v: f64| (v + m) * s;
    let mut doc = Document::new()
        .set("width", format!("{w_mm}mm"))
        .set("height", format!("{h_mm}mm"))
        .set("viewBox", (0.0, 0.0, w_mm, h_mm))
        .add(
            Rectangle::new()
                .set("width", w_mm)
                .set("height", h_mm)
                .set("fill", "#ffffff"),
        );
    let (squares, circles) = shapes(spec);
    for (col, row) in squares {
        doc = doc.add(
            Rectangle::new()
                .set("x", mm(col as f64))
                .set("y", mm(row as f64))
                .set("width", s)
                .set("height", s)
                .set("fill", "#000000"),
        );
    }
    for (c, black) in circles {
        doc = doc.add(
            Circle::new()
                .set("cx", mm(c[0]))
                .set("cy", mm(c[1]))
                .set("r", spec.circle_radius * s)
                .set("fill", if black { "#000000" } else { "#ffffff" }),
        );
    }
    Ok(doc.to_string())
}

/// zlib-wrapped deflate, what a PDF's FlateDecode filter reads.
fn zlib_deflate(data: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    // Writing to a Vec cannot fail.
    let _ = z.write_all(data);
    z.finish().unwrap_or_default()
}

/// A one-page PDF whose page is the chart at its physical size.
///
/// # Errors
/// An invalid spec.
pub fn to_pdf(spec: &ChartSpec) -> Result<Vec<u8>, ExportError> {
    use pdf_writer::{Content, Filter, Pdf, Rect, Ref};
    spec.validate()
        .map_err(|e| ExportError::Invalid(e.to_string()))?;
    let (w_mm, h_mm) = spec.paper_mm();
    let (w_pt, h_pt) = ((w_mm * PT_PER_MM) as f32, (h_mm * PT_PER_MM) as f32);
    let pt_per_unit = spec.square_mm * PT_PER_MM;
    let m = spec.margin;
    // PDF's y axis points up from the bottom of the page.
    let at = |x: f64, y: f64| -> (f32, f32) {
        (
            ((x + m) * pt_per_unit) as f32,
            h_pt - ((y + m) * pt_per_unit) as f32,
        )
    };
    let mut content = Content::new();
    content.set_fill_gray(0.0);
    let (squares, circles) = shapes(spec);
    for (col, row) in squares {
        let (x0, y1) = at(col as f64, row as f64 + 1.0);
        content.rect(x0, y1, pt_per_unit as f32, pt_per_unit as f32);
    }
    content.fill_nonzero();
    // A circle as four cubic Béziers (κ = 0.5523 puts the midpoints on the circle to
    // within 0.03 % of the radius).
    let r = (spec.circle_radius * pt_per_unit) as f32;
    let k = 0.552_284_8 * r;
    for black in [true, false] {
        content.set_fill_gray(if black { 0.0 } else { 1.0 });
        for (c, b) in &circles {
            if *b != black {
                continue;
            }
            let (cx, cy) = at(c[0], c[1]);
            content.move_to(cx + r, cy);
            content.cubic_to(cx + r, cy + k, cx + k, cy + r, cx, cy + r);
            content.cubic_to(cx - k, cy + r, cx - r, cy + k, cx - r, cy);
            content.cubic_to(cx - r, cy - k, cx - k, cy - r, cx, cy - r);
            content.cubic_to(cx + k, cy - r, cx + r, cy - k, cx + r, cy);
            content.close_path();
        }
        content.fill_nonzero();
    }
    let (catalog, tree, page, stream) = (Ref::new(1), Ref::new(2), Ref::new(3), Ref::new(4));
    let mut pdf = Pdf::new();
    pdf.catalog(catalog).pages(tree);
    pdf.pages(tree).kids([page]).count(1);
    {
        let mut p = pdf.page(page);
        p.media_box(Rect::new(0.0, 0.0, w_pt, h_pt));
        p.parent(tree);
        p.contents(stream);
    }
    // Two thousand circles of plain operators deflate to a tenth of their size.
    let bytes = zlib_deflate(&content.finish());
    pdf.stream(stream, &bytes).filter(Filter::FlateDecode);
    Ok(pdf.finish())
}

/// The chart rasterised exactly at `dpi` (8-bit grey is enough for printing; the
/// plane is what the rasteriser computed, white = 1).
///
/// # Errors
/// An invalid spec or DPI, or an image too large to be meant.
pub fn to_plane(spec: &ChartSpec, dpi: f64) -> Result<Plane, ExportError> {
    spec.validate()
        .map_err(|e| ExportError::Invalid(e.to_string()))?;
    if !(dpi.is_finite() && (10.0..=4800.0).contains(&dpi)) {
        return Err(ExportError::Invalid(format!(
            "DPI must be 10–4800 (got {dpi})"
        )));
    }
    let px_per_unit = spec.square_mm * dpi / 25.4;
    let (w_mm, h_mm) = spec.paper_mm();
    let (w, h) = (
        (w_mm * dpi / 25.4).round().max(1.0),
        (h_mm * dpi / 25.4).round().max(1.0),
    );
    if w * h > MAX_PNG_PIXELS {
        return Err(ExportError::TooLarge(format!(
            "a {w} × {h} px image at {dpi} DPI is too large; lower --dpi"
        )));
    }
    let m = spec.margin;
    // Pixel (i, j) covers [i − ½, i + ½]: the paper's corner sits on the first pixel's
    // outer edge.
    let image_from_chart = Homography::translation(-0.5, -0.5)
        .compose(&Homography::scaling(px_per_unit, px_per_unit))
        .compose(&Homography::translation(m, m));
    Ok(rasterize(
        spec,
        &image_from_chart,
        w as usize,
        h as usize,
        1.0,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> ChartSpec {
        ChartSpec {
            cols: 6,
            rows: 4,
            ..ChartSpec::default()
        }
    }

    #[test]
    fn svg_has_every_square_and_circle() {
        let spec = small();
        let svg = to_svg(&spec).expect("svg");
        assert!(svg.contains(r#"width="160mm""#), "{}", &svg[..200]);
        // Background + black squares.
        assert_eq!(svg.matches("<rect").count(), 1 + spec.cols * spec.rows / 2);
        assert_eq!(svg.matches("<circle").count(), 5 * spec.cols * spec.rows);
    }

    #[test]
    fn pdf_page_is_the_physical_size() {
        let spec = small();
        let pdf = to_pdf(&spec).expect("pdf");
        assert!(pdf.starts_with(b"%PDF-"));
        let text = String::from_utf8_lossy(&pdf);
        let (w, h) = spec.paper_mm();
        let media = format!("/MediaBox [0 0 {} {}]", w * PT_PER_MM, h * PT_PER_MM);
        let w_pt = format!("{:.3}", w * PT_PER_MM);
        assert!(
            text.contains("/MediaBox [0 0 453.5") && text.contains(&w_pt[..5]),
            "no {media} in the PDF"
        );
        // The content stream inflates to every square and four Béziers per circle.
        assert!(text.contains("/Filter /FlateDecode"));
        let start = pdf
            .windows(7)
            .position(|w| w == b"stream\n")
            .expect("a stream")
            + 7;
        let end = pdf
            .windows(10)
            .position(|w| w == b"\nendstream")
            .expect("its end");
        let mut content = String::new();
        std::io::Read::read_to_string(
            &mut flate2::read::ZlibDecoder::new(&pdf[start..end]),
            &mut content,
        )
        .expect("inflates");
        let ops = |op: &str| content.lines().filter(|l| l.ends_with(op)).count();
        assert_eq!(ops(" re"), spec.cols * spec.rows / 2, "squares");
        assert_eq!(ops(" c"), 4 * 5 * spec.cols * spec.rows, "circle arcs");
    }

    #[test]
    fn png_white_fraction_is_the_charts() {
        let spec = small();
        let plane = to_plane(&spec, 100.0).expect("plane");
        let (cols, rows) = (spec.cols as f64, spec.rows as f64);
        let n = cols * rows;
        // The image is a whole number of pixels: the area it covers (beyond the paper
        // it is white background) in chart units².
        let px_per_unit = spec.square_mm * 100.0 / 25.4;
        let total = (plane.width * plane.height) as f64 / px_per_unit.powi(2);
        let circles = 5.0 * std::f64::consts::PI * spec.circle_radius.powi(2);
        // Half the squares are black; their circles are white, the others' black.
        let black = n / 2.0 * (1.0 - circles) + n / 2.0 * circles;
        let want = 1.0 - black / total;
        let got = plane.mean();
        assert!((got - want).abs() < 1e-5, "white fraction {got} vs {want}");
        assert!(to_plane(&spec, 100_000.0).is_err());
    }
}
