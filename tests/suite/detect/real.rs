//! Real photographs of a printed chessboard (tests/data/real/charts, SOURCES.md there):
//! lensblur's detection beside OpenCV's findChessboardCornersSB, whose result on each
//! photo `scripts/opencv_real_charts.py` recorded in `opencv.json`; and the same photos
//! turned, which must be found as often as upright.

use lensblur::chart::ChartSpec;
use lensblur::detect::{DetectParams, Detection, SquareStatus, detect};
use lensblur::job::JobContext;
use lensblur::plane::{Capture, ChannelPlane, Plane};
use lensblur::raw::{LoadOptions, load_capture};
use serde::Deserialize;
use std::path::{Path, PathBuf};

fn folder() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real/charts")
}

fn spec() -> ChartSpec {
    ChartSpec::load(&folder().join("chart.json")).expect("the photos' chart spec")
}

#[derive(Deserialize)]
struct OpenCv {
    photos: Vec<OpenCvPhoto>,
}

#[derive(Deserialize)]
struct OpenCvPhoto {
    file: String,
    found: bool,
    corners: Vec<[f64; 2]>,
    found_turned: std::collections::BTreeMap<String, bool>,
}

fn opencv() -> OpenCv {
    let text = std::fs::read_to_string(folder().join("opencv.json")).expect("opencv.json");
    serde_json::from_str(&text).expect("opencv.json parses")
}

fn photo(file: &str) -> Capture {
    load_capture(&folder().join(file), &LoadOptions::default()).expect("photo loads")
}

/// A `nw` × `nh` capture whose every plane is `value(plane, x, y)`.
fn remap(
    cap: &Capture,
    nw: usize,
    nh: usize,
    value: impl Fn(&Plane, usize, usize) -> f32,
) -> Capture {
    let planes = cap
        .planes
        .iter()
        .map(|cp| {
            assert_eq!(cp.step, 1, "a photo's planes are full resolution");
            ChannelPlane {
                plane: Plane::from_fn(nw, nh, |x, y| value(&cp.plane, x, y)),
                ..cp.clone()
            }
        })
        .collect();
    Capture {
        width: nw,
        height: nh,
        planes,
        ..cap.clone()
    }
}

/// Each plane turned clockwise by `quarters` quarter turns: an exact permutation of
/// the pixels, as a camera held on its side would have taken them.
fn turn_quarters(cap: &Capture, quarters: usize) -> Capture {
    let q = quarters % 4;
    let (w, h) = (cap.width, cap.height);
    let (nw, nh) = if q % 2 == 1 { (h, w) } else { (w, h) };
    remap(cap, nw, nh, |p, x, y| {
        // Where the turned pixel (x, y) came from.
        let (sx, sy) = match q {
            0 => (x, y),
            1 => (y, h - 1 - x),
            2 => (w - 1 - x, h - 1 - y),
            _ => (w - 1 - y, x),
        };
        p.get(sx, sy)
    })
}

/// Each plane turned clockwise by `degrees` about its centre into a frame large enough
/// to hold it all, bilinear, the corners beyond the photo filled with the photo's mean.
fn turn_by(cap: &Capture, degrees: f64) -> Capture {
    let (c, s) = (degrees.to_radians().cos(), degrees.to_radians().sin());
    let (w, h) = (cap.width as f64, cap.height as f64);
    let nw = (w * c.abs() + h * s.abs()).ceil() as usize;
    let nh = (w * s.abs() + h * c.abs()).ceil() as usize;
    let means: Vec<f32> = cap
        .planes
        .iter()
        .map(|cp| {
            let d = &cp.plane.data;
            (d.iter().map(|&v| f64::from(v)).sum::<f64>() / d.len() as f64) as f32
        })
        .collect();
    let mean = means.iter().sum::<f32>() / means.len().max(1) as f32;
    remap(cap, nw, nh, |p, x, y| {
        let dx = x as f64 - (nw as f64 - 1.0) / 2.0;
        let dy = y as f64 - (nh as f64 - 1.0) / 2.0;
        // Clockwise on screen (y down) by θ: the source is the destination turned back.
        let sx = c * dx + s * dy + (w - 1.0) / 2.0;
        let sy = -s * dx + c * dy + (h - 1.0) / 2.0;
        if sx < 0.0 || sy < 0.0 || sx > w - 1.0 || sy > h - 1.0 {
            return mean;
        }
        let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(p.width - 1), (y0 + 1).min(p.height - 1));
        let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
        let a = p.get(x0, y0) * (1.0 - fx) + p.get(x1, y0) * fx;
        let b = p.get(x0, y1) * (1.0 - fx) + p.get(x1, y1) * fx;
        a * (1.0 - fy) + b * fy
    })
}

/// Where a point of the photo turned by `quarters` quarter turns lies in the photo.
fn back_from_quarters(p: [f64; 2], quarters: usize, w: usize, h: usize) -> [f64; 2] {
    let (wm, hm) = ((w - 1) as f64, (h - 1) as f64);
    match quarters % 4 {
        0 => p,
        1 => [p[1], hm - p[0]],
        2 => [wm - p[0], hm - p[1]],
        _ => [wm - p[1], p[0]],
    }
}

/// Where a point of the photo turned by `degrees` ([`turn_by`]) lies in the photo.
fn back_from_degrees(p: [f64; 2], degrees: f64, turned: &Capture, w: usize, h: usize) -> [f64; 2] {
    let (c, s) = (degrees.to_radians().cos(), degrees.to_radians().sin());
    let dx = p[0] - (turned.width as f64 - 1.0) / 2.0;
    let dy = p[1] - (turned.height as f64 - 1.0) / 2.0;
    [
        c * dx + s * dy + (w as f64 - 1.0) / 2.0,
        -s * dx + c * dy + (h as f64 - 1.0) / 2.0,
    ]
}

/// The largest distance between a square's inner corners (those on the board's own
/// edge are located only by the squares' edges against what lies beyond the print)
/// in `turned`, taken back into the upright photo by `back`, and the same square's
/// upright, over the squares aligned in both; and how many those are.
fn worst_disagreement(
    spec: &ChartSpec,
    upright: &Detection,
    turned: &Detection,
    back: impl Fn([f64; 2]) -> [f64; 2],
) -> (f64, usize) {
    let mut worst = 0.0f64;
    let mut n = 0;
    for s in upright.ok_squares() {
        let Some(t) = turned
            .ok_squares()
            .find(|t| t.col == s.col && t.row == s.row)
        else {
            continue;
        };
        n += 1;
        for (k, c) in spec.square_corners(s.col, s.row).iter().enumerate() {
            if !is_inner_corner(spec, *c) {
                continue;
            }
            let b = back(t.corners[k]);
            worst = worst.max((b[0] - s.corners[k][0]).hypot(b[1] - s.corners[k][1]));
        }
    }
    (worst, n)
}

/// Whether chart point `c` is one of the board's inner corners (where four squares
/// meet), which both detectors locate.
fn is_inner_corner(spec: &ChartSpec, c: [f64; 2]) -> bool {
    c[0] >= 1.0 && c[1] >= 1.0 && c[0] <= (spec.cols - 1) as f64 && c[1] <= (spec.rows - 1) as f64
}

fn run(cap: &Capture, spec: &ChartSpec) -> Option<Detection> {
    detect(cap, spec, &DetectParams::default(), &JobContext::silent()).ok()
}

/// Squares of the board that are interior (all four corners inner corners of the
/// board, which both detectors locate), and how many of them were aligned.
fn interior_ok(det: &Detection, spec: &ChartSpec) -> (usize, usize) {
    let interior = |s: &&lensblur::detect::SquareAlignment| {
        s.col >= 1 && s.row >= 1 && s.col + 1 < spec.cols && s.row + 1 < spec.rows
    };
    let n = det.squares.iter().filter(interior).count();
    let ok = det
        .squares
        .iter()
        .filter(interior)
        .filter(|s| s.status == SquareStatus::Ok)
        .count();
    (ok, n)
}

/// The aligned inner corners against OpenCV's: each of ours to its nearest of OpenCV's
/// (the two detectors may number the board from different corners). RMS and worst, px.
fn agreement(det: &Detection, spec: &ChartSpec, cv: &[[f64; 2]]) -> (f64, f64, usize) {
    let mut d2 = Vec::new();
    for s in det.ok_squares() {
        let chart = spec.square_corners(s.col, s.row);
        for (k, c) in chart.iter().enumerate() {
            if !is_inner_corner(spec, *c) {
                continue;
            }
            let p = s.corners[k];
            let best = cv
                .iter()
                .map(|q| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2))
                .fold(f64::INFINITY, f64::min);
            d2.push(best);
        }
    }
    let n = d2.len();
    let rms = (d2.iter().sum::<f64>() / n.max(1) as f64).sqrt();
    let worst = d2.iter().copied().fold(0.0, f64::max).sqrt();
    (rms, worst, n)
}

/// docs/figures.md's figures on the 26 photos: the board found on every one, upright and
/// turned; at least 1811 of the 1820 squares aligned, interior 1040 of 1040 (none set
/// aside, clipped or not); the quarter turns (exact permutations of the pixels) align
/// as many squares as upright on every photo, 30° at least 1813 in all; and the aligned
/// inner corners within half a pixel RMS of OpenCV's on every photo.
#[test]
#[ignore = "figures, about a minute: cargo test --test suite real_chart_figures -- --ignored --nocapture"]
fn real_chart_figures() {
    let spec = spec();
    let cv = opencv();
    assert_eq!(cv.photos.len(), 26);
    let (mut aligned, mut squares, mut interior, mut interior_aligned) = (0, 0, 0, 0);
    let mut turned = [0usize; 4];
    for p in cv.photos {
        let cap = photo(&p.file);
        let det = run(&cap, &spec);
        let mut line = format!(
            "{}: OpenCV {} |",
            p.file,
            if p.found { "found" } else { "not found" }
        );
        let Some(d) = &det else {
            panic!("{line} lensblur not found");
        };
        let (ok, n) = interior_ok(d, &spec);
        let all = d.ok_squares().count();
        let (rms, worst, m) = agreement(d, &spec, &p.corners);
        line += &format!(
            " lensblur {all}/{} squares, interior {ok}/{n}, vs OpenCV {m} corners RMS {rms:.3} px worst {worst:.3} px",
            d.squares.len()
        );
        let mut reasons = std::collections::BTreeMap::<String, usize>::new();
        for s in &d.squares {
            if let Some(r) = &s.reason {
                *reasons.entry(r.clone()).or_default() += 1;
            }
        }
        line += &format!(" {reasons:?}");
        assert_eq!(ok, n, "{}: interior squares not aligned", p.file);
        assert!(
            m > 0 && rms <= 0.5,
            "{}: {m} corners, RMS {rms:.3} px off OpenCV's",
            p.file
        );
        aligned += all;
        squares += d.squares.len();
        interior += n;
        interior_aligned += ok;
        for q in 1..4 {
            let t = run(&turn_quarters(&cap, q), &spec)
                .unwrap_or_else(|| panic!("{} turned {}°: not found", p.file, 90 * q));
            let count = t.ok_squares().count();
            line += &format!(" | {}°: {count} ok", 90 * q);
            assert_eq!(count, all, "{} turned {}°", p.file, 90 * q);
            turned[q - 1] += count;
        }
        let t = run(&turn_by(&cap, 30.0), &spec)
            .unwrap_or_else(|| panic!("{} turned 30°: not found", p.file));
        line += &format!(" | 30°: {} ok", t.ok_squares().count());
        turned[3] += t.ok_squares().count();
        eprintln!("{line}");
    }
    eprintln!(
        "{aligned} of {squares} squares aligned, interior {interior_aligned}/{interior}; at 90°, 180°, 270°, 30°: {turned:?}"
    );
    assert_eq!((interior_aligned, interior), (1040, 1040));
    assert!(aligned >= 1811, "{aligned} of {squares} squares aligned");
    assert!(turned[3] >= 1813, "{} squares aligned at 30°", turned[3]);
}

/// The 9 × 7 chessboard laid on a corrugated panel whose stripes fill the rest of the
/// frame (striped/, SOURCES.md): their saddles outnumber the board's corners by far and
/// line up in a lattice of their own, larger than the chart. The board is found, and
/// every interior square (the 7 × 5 whose corners are all inner corners) is aligned or
/// set aside because its white is clipped.
#[test]
fn chart_on_a_striped_panel() {
    let folder = folder().join("striped");
    let spec = ChartSpec::load(&folder.join("chart.json")).expect("the print's spec");
    for file in ["striped-panel-1.jpg", "striped-panel-2.jpg"] {
        let cap = load_capture(&folder.join(file), &LoadOptions::default()).expect("loads");
        let det = detect(&cap, &spec, &DetectParams::default(), &JobContext::silent())
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let (ok, n) = interior_ok(&det, &spec);
        let clipped = det
            .squares
            .iter()
            .filter(|s| s.col >= 1 && s.row >= 1 && s.col + 1 < spec.cols && s.row + 1 < spec.rows)
            .filter(|s| lensblur::detect::is_clipped(s))
            .count();
        let mut reasons = std::collections::BTreeMap::<String, usize>::new();
        for s in &det.squares {
            if let Some(r) = &s.reason {
                *reasons.entry(r.clone()).or_default() += 1;
            }
        }
        eprintln!(
            "{file}: {} of {} squares aligned, interior {ok}/{n} aligned, {clipped} clipped; {reasons:?}",
            det.ok_squares().count(),
            det.squares.len()
        );
        assert_eq!(n, (spec.cols - 2) * (spec.rows - 2));
        assert_eq!(ok + clipped, n, "{file}: interior squares lost");
        assert!(det.ok_squares().count() >= n, "{file}: squares aligned");
    }
}

/// Every photo on which OpenCV finds the board, lensblur finds too; every interior
/// square (the 8 × 5 whose corners are all inner corners, which both locate) is
/// aligned or set aside because its white is clipped (a clipped edge's blur cannot be
/// measured; OpenCV needs no blur); and where both locate a corner they agree to half
/// a pixel RMS (measured 0.11–0.40 px over these 26 photos).
#[test]
fn real_photos_as_opencv_finds_them() {
    let spec = spec();
    let cv = opencv();
    assert_eq!(cv.photos.len(), 26);
    for p in &cv.photos {
        assert!(p.found, "{}: OpenCV found this board when recorded", p.file);
        let det = run(&photo(&p.file), &spec)
            .unwrap_or_else(|| panic!("{}: OpenCV finds the board, lensblur not", p.file));
        let (ok, n) = interior_ok(&det, &spec);
        let clipped = det
            .squares
            .iter()
            .filter(|s| s.col >= 1 && s.row >= 1 && s.col + 1 < spec.cols && s.row + 1 < spec.rows)
            .filter(|s| {
                s.reason
                    .as_deref()
                    .is_some_and(|r| r.starts_with("saturated"))
            })
            .count();
        let (rms, worst, m) = agreement(&det, &spec, &p.corners);
        eprintln!(
            "{}: interior {ok}/{n} aligned, {clipped} clipped; {} of {} squares; {m} corners vs OpenCV RMS {rms:.3} px, worst {worst:.3} px",
            p.file,
            det.ok_squares().count(),
            det.squares.len()
        );
        assert_eq!(ok + clipped, n, "{}: interior squares lost", p.file);
        assert!(
            m > 0 && rms <= 0.5,
            "{}: {m} corners, RMS {rms:.3} px off OpenCV's",
            p.file
        );
    }
}

/// The photos turned by quarter turns (a camera on its side, or upside down) and by
/// 30°: found whenever upright, each square the same square of the print (the 10 × 7
/// board's colours allow one correspondence), the quarter turns aligning the same
/// squares, their inner corners within a tenth of a pixel (measured at most 0.051 px;
/// the registration is not exactly equivariant, its coarse level sampling every other
/// pixel from the window's corner), within half a pixel at 30° (measured at most
/// 0.41 px: the resampled photo is softer). OpenCV found every one turned too
/// (opencv.json). A portrait board (left01), one partly out of frame (right03) and
/// one mostly clipped (left12).
#[test]
fn turned_photos_are_found_as_upright() {
    let spec = spec();
    let cv = opencv();
    for file in ["left01.jpg", "right03.jpg", "left12.jpg"] {
        let rec = cv.photos.iter().find(|p| p.file == file).expect("recorded");
        let cap = photo(file);
        let upright = run(&cap, &spec).expect("found upright");
        let n_up = upright.ok_squares().count();
        for q in 1..4usize {
            assert!(
                rec.found_turned[&(90 * q).to_string()],
                "{file}: OpenCV at {}°",
                90 * q
            );
            let det = run(&turn_quarters(&cap, q), &spec)
                .unwrap_or_else(|| panic!("{file} turned {}°: not found", 90 * q));
            let (worst, n) = worst_disagreement(&spec, &upright, &det, |p| {
                back_from_quarters(p, q, cap.width, cap.height)
            });
            eprintln!(
                "{file} {}°: {} aligned (upright {n_up}); {n} in both, corners differ by at most {worst:.4} px",
                90 * q,
                det.ok_squares().count()
            );
            assert_eq!(det.ok_squares().count(), n_up, "{file} {}°", 90 * q);
            assert_eq!(n, n_up, "{file} {}°: the same squares", 90 * q);
            // A wrong correspondence would put them a square (over 20 px) apart.
            assert!(worst < 0.1, "{file} {}°: corners {worst} px apart", 90 * q);
        }
        let turned = turn_by(&cap, 30.0);
        let det = run(&turned, &spec).unwrap_or_else(|| panic!("{file} turned 30°: not found"));
        let (worst, n) = worst_disagreement(&spec, &upright, &det, |p| {
            back_from_degrees(p, 30.0, &turned, cap.width, cap.height)
        });
        eprintln!(
            "{file} 30°: {} aligned (upright {n_up}); {n} in both, corners differ by at most {worst:.3} px",
            det.ok_squares().count()
        );
        // Resampled, the photo is softer, and a different set of its squares may
        // clip; the squares both align must be the same squares of the print.
        assert!(
            n > 0 && worst < 0.5,
            "{file} 30°: {n} squares in both, {worst} px apart"
        );
    }
}
