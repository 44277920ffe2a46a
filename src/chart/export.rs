//! The chart for printing: SVG and PDF at its physical size (vector, exact circles),
//! PNG at a chosen resolution through the exact rasteriser.

use super::{ChartSpec, NOTES_MM, PRINTER_MARGIN_MM, Paper, rasterize};
use crate::geometry::Homography;
use crate::plane::Plane;
use crate::plane::millimetres;

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

/// Where the PDF puts the chart: the page, and the chart's top-left corner on it, in
/// millimetres from the page's top-left.
struct PageLayout {
    page_mm: (f64, f64),
    chart_at_mm: (f64, f64),
    /// What the notes call the page: "A4 landscape", or its size.
    page_name: String,
}

/// The page: `paper` (or, without one, the first sheet the chart fits on, else the
/// chart's own size with its notes), the chart centred across it and, with its notes
/// strip below, down it.
fn page_layout(spec: &ChartSpec, paper: Option<Paper>) -> Result<PageLayout, ExportError> {
    let (cw, ch) = spec.paper_mm();
    let sheet = match paper {
        Some(p) if !spec.fits(p) => {
            return Err(ExportError::Invalid(format!(
                "the chart ({} × {} mm) and its notes do not fit on {p} inside a {} mm printer margin",
                millimetres(cw),
                millimetres(ch),
                millimetres(PRINTER_MARGIN_MM)
            )));
        }
        Some(p) => Some(p),
        None => spec.sheet(),
    };
    let (page_mm, page_name) = match sheet {
        Some(p) => (p.landscape_mm(), format!("{p} landscape")),
        None => {
            // No sheet: the page is the chart and its notes, wide enough for the bar.
            let size = (cw.max(SCALE_BAR_MM + 4.0), ch + NOTES_MM);
            let name = format!(
                "a {} × {} mm page",
                millimetres(size.0),
                millimetres(size.1)
            );
            (size, name)
        }
    };
    Ok(PageLayout {
        page_mm,
        chart_at_mm: ((page_mm.0 - cw) / 2.0, (page_mm.1 - ch - NOTES_MM) / 2.0),
        page_name,
    })
}

/// The scale bar's length: a ruler checks it at a glance.
const SCALE_BAR_MM: f64 = 100.0;

/// Text as the PDF's standard fonts encode it (WinAnsi, which agrees with Latin-1 for
/// every character the notes use).
fn win_ansi(text: &str) -> Vec<u8> {
    text.chars()
        .map(|c| u8::try_from(u32::from(c)).unwrap_or(b'?'))
        .collect()
}

/// The notes strip below the chart: a 100 mm scale bar with a tick every 10 mm, and
/// beside it how to print and what the chart is.
fn draw_notes(
    content: &mut pdf_writer::Content,
    spec: &ChartSpec,
    layout: &PageLayout,
    font: pdf_writer::Name<'_>,
) {
    let (left, top) = (
        layout.chart_at_mm.0,
        layout.chart_at_mm.1 + spec.paper_mm().1,
    );
    let page_h = layout.page_mm.1;
    let pt = |x_mm: f64, y_mm: f64| {
        (
            (x_mm * PT_PER_MM) as f32,
            ((page_h - y_mm) * PT_PER_MM) as f32,
        )
    };
    content.set_fill_gray(0.0);
    content.set_stroke_gray(0.0);
    content.set_line_width((0.25 * PT_PER_MM) as f32);
    let bar_y = top + 3.5;
    let x0 = left + 2.0;
    let (a, b) = (pt(x0, bar_y), pt(x0 + SCALE_BAR_MM, bar_y));
    content.move_to(a.0, a.1);
    content.line_to(b.0, b.1);
    for i in 0..=10 {
        let x = x0 + f64::from(i) * SCALE_BAR_MM / 10.0;
        let tall = if i % 5 == 0 { 2.5 } else { 1.5 };
        let (p, q) = (pt(x, bar_y), pt(x, bar_y - tall));
        content.move_to(p.0, p.1);
        content.line_to(q.0, q.1);
    }
    content.stroke();
    let (w, h) = spec.paper_mm();
    let lines = [
        (x0, bar_y + 3.5, "0".to_string()),
        (
            x0 + SCALE_BAR_MM - 8.0,
            bar_y + 3.5,
            format!("{} mm", millimetres(SCALE_BAR_MM)),
        ),
        (
            x0 + SCALE_BAR_MM + 8.0,
            top + 3.5,
            "Print at 100 % / actual size, never \"fit to page\": the bar is 100 mm; check it with a ruler."
                .to_string(),
        ),
        (
            x0 + SCALE_BAR_MM + 8.0,
            top + 7.5,
            format!(
                "{} × {} squares of {} mm; chart {} × {} mm, on {}.",
                spec.cols,
                spec.rows,
                millimetres(spec.square_mm),
                millimetres(w),
                millimetres(h),
                layout.page_name
            ),
        ),
    ];
    content.begin_text();
    content.set_font(font, 7.0);
    for (x, y, text) in lines {
        let (x, y) = pt(x, y);
        content.set_text_matrix([1.0, 0.0, 0.0, 1.0, x, y]);
        content.show(pdf_writer::Str(&win_ansi(&text)));
    }
    content.end_text();
}

/// A one-page PDF whose page is the sheet it is printed on (`paper`, or without one
/// the first sheet the chart fits on, else the chart's own size): the chart centred
/// at its physical size, and below it how to print it and a 100 mm scale bar to check
/// the print with.
///
/// # Errors
/// An invalid spec, or a chart that does not fit on `paper`.
pub fn to_pdf(spec: &ChartSpec, paper: Option<Paper>) -> Result<Vec<u8>, ExportError> {
    use pdf_writer::{Content, Filter, Name, Pdf, Rect, Ref};
    spec.validate()
        .map_err(|e| ExportError::Invalid(e.to_string()))?;
    let layout = page_layout(spec, paper)?;
    let (page_w, page_h) = layout.page_mm;
    let (w_pt, h_pt) = ((page_w * PT_PER_MM) as f32, (page_h * PT_PER_MM) as f32);
    let pt_per_unit = spec.square_mm * PT_PER_MM;
    let m = spec.margin;
    let (ox, oy) = (
        layout.chart_at_mm.0 * PT_PER_MM,
        layout.chart_at_mm.1 * PT_PER_MM,
    );
    // PDF's y axis points up from the bottom of the page.
    let at = |x: f64, y: f64| -> (f32, f32) {
        (
            (ox + (x + m) * pt_per_unit) as f32,
            h_pt - (oy + (y + m) * pt_per_unit) as f32,
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
    let font_name = Name(b"F1");
    draw_notes(&mut content, spec, &layout, font_name);
    let (catalog, tree, page, stream, font) = (
        Ref::new(1),
        Ref::new(2),
        Ref::new(3),
        Ref::new(4),
        Ref::new(5),
    );
    let mut pdf = Pdf::new();
    pdf.catalog(catalog).pages(tree);
    pdf.pages(tree).kids([page]).count(1);
    {
        let mut p = pdf.page(page);
        p.media_box(Rect::new(0.0, 0.0, w_pt, h_pt));
        p.parent(tree);
        p.contents(stream);
        p.resources().fonts().pair(font_name, font);
    }
    // Helvetica is one of the fonts every PDF reader has: nothing to embed.
    pdf.type1_font(font)
        .base_font(Name(b"Helvetica"))
        .encoding_predefined(Name(b"WinAnsiEncoding"));
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

    /// The content stream of a one-stream PDF, inflated.
    fn content_of(pdf: &[u8]) -> String {
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
        content
    }

    #[test]
    fn pdf_page_is_the_sheet_with_the_chart_centred_on_it() {
        let spec = small();
        let pdf = to_pdf(&spec, Some(Paper::A4)).expect("pdf");
        assert!(pdf.starts_with(b"%PDF-"));
        let text = String::from_utf8_lossy(&pdf);
        // A4 landscape: 297 × 210 mm in points.
        assert!(
            text.contains("/MediaBox [0 0 841.8") && text.contains(" 595.27"),
            "the page is not A4"
        );
        // Without a paper, the first sheet it fits: A4 again for 160 × 120 mm.
        assert_eq!(to_pdf(&spec, None).expect("pdf"), pdf);
        // The content stream inflates to every square and four Béziers per circle.
        assert!(text.contains("/Filter /FlateDecode"));
        let content = content_of(&pdf);
        let ops = |op: &str| content.lines().filter(|l| l.ends_with(op)).count();
        assert_eq!(ops(" re"), spec.cols * spec.rows / 2, "squares");
        assert_eq!(ops(" c"), 4 * 5 * spec.cols * spec.rows, "circle arcs");
        // The first black square's left edge: the chart's 160 mm centred across 297.
        let first = content
            .lines()
            .find(|l| l.ends_with(" re"))
            .expect("a square");
        let x: f64 = first
            .split(' ')
            .next()
            .and_then(|v| v.parse().ok())
            .expect("x");
        let want = ((297.0 - 160.0) / 2.0 + spec.margin * spec.square_mm) * PT_PER_MM;
        assert!((x - want).abs() < 0.01, "square at {x} pt, not {want}");
        assert!(
            content.contains("Print at 100 % / actual size"),
            "{content}"
        );
        // Not ASCII (the "×"): a hex string of its WinAnsi bytes.
        let hex: String = win_ansi("6 × 4 squares of 20 mm")
            .iter()
            .map(|b| format!("{b:02X}"))
            .collect();
        assert!(content.to_uppercase().contains(&hex), "{content}");
        // Eleven ticks and the bar.
        assert_eq!(ops(" l"), 12, "scale bar");
        // A chart too large for the sheet is refused, naming it.
        let err = to_pdf(&ChartSpec::default(), Some(Paper::A4)).expect_err("too large");
        assert!(err.to_string().contains("A4"), "{err}");
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
