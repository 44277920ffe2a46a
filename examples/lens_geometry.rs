//! The lensfun figures: a zoom with known geometry (barrel turning to pincushion along
//! the zoom, ±3 × 10⁻⁴ lateral colour, 1.5 to 0.5 stops of fall-off) shot at every
//! focal length and aperture of a grid, each shot simulated, detected and fitted as
//! `lensblur lensfun` does; the fitted geometry against the simulator's truth:
//! distortion (the displacement at the frame corner and the largest error along the
//! diagonal, px), lateral colour at the corners (px) and fall-off at the corners and
//! where the chart reached (stops).
//!
//! `cargo run --release --example lens_geometry -- [W H] [raw|rgb] [focal=5] [aperture=3]`

use lensblur::chart::ChartSpec;
use lensblur::correction::{CorrectionOptions, GeometryShot, measure};
use lensblur::detect::{DetectParams, detect};
use lensblur::job::JobContext;
use lensblur::plane::{Channel, LensSetting};
use lensblur::simulate::{CaptureParams, LensGeometry, Pose, VirtualLens, simulate_shot};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size = |i: usize, d: usize| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let (w, h) = (size(0, 2400), size(1, 1600));
    let raw = !args.iter().any(|a| a == "rgb");
    let option = |name: &str, default: usize| {
        args.iter()
            .filter_map(|a| a.strip_prefix(name)?.strip_prefix('='))
            .find_map(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let lens = VirtualLens {
        geometry: LensGeometry {
            distortion_wide: [-0.03, 0.004],
            distortion_long: [0.015, -0.002],
            lateral_colour: [3e-4, -3e-4],
            vignetting_stops: [1.5, 0.5],
        },
        ..VirtualLens::demo()
    };
    let settings = lens.setting_grid(option("focal", 5), option("aperture", 3));
    let chart = ChartSpec::default();
    let job = JobContext::silent();
    let t0 = std::time::Instant::now();
    let mut detections = Vec::new();
    for (k, &s) in settings.iter().enumerate() {
        let mut p = CaptureParams::new(w, h, s);
        p.bayer = raw;
        p.seed = 100 + k as u64;
        // Poses as a photographer's: a little rotation, tilt and shift per shot.
        let wobble = |i: u64| ((k as u64 * 7 + i * 13) % 11) as f64 / 10.0 - 0.5;
        p.pose = Pose {
            rotation_deg: 3.0 * wobble(1),
            tilt_x: 0.03 * wobble(2),
            tilt_y: 0.03 * wobble(3),
            fill: 0.9,
            shift_px: [0.01 * w as f64 * wobble(4), 0.01 * h as f64 * wobble(5)],
        };
        let shot = simulate_shot(&chart, &lens, &p, &job)?;
        let d = detect(&shot.capture, &chart, &DetectParams::default(), &job)?;
        eprintln!(
            "{} mm f/{:.1}: {} squares aligned ({:.0} s)",
            s.focal_mm,
            s.f_number,
            d.ok_squares().count(),
            t0.elapsed().as_secs_f64()
        );
        detections.push((s, d));
    }
    let names: Vec<String> = settings
        .iter()
        .map(|s| format!("{} mm f/{}", s.focal_mm, s.f_number))
        .collect();
    let shots: Vec<GeometryShot<'_>> = detections
        .iter()
        .zip(&names)
        .map(|((s, d), name)| GeometryShot {
            name,
            setting: *s,
            detection: d,
        })
        .collect();
    let t1 = std::time::Instant::now();
    let c = measure(&shots, &chart, CorrectionOptions::default())?;
    println!(
        "{w} × {h} {}, {} shots: fitted in {:.2} s; distortion model {}, lateral colour {}",
        if raw { "RAW (Bayer)" } else { "RGB" },
        shots.len(),
        t1.elapsed().as_secs_f64(),
        c.distortion_model.name(),
        c.tca_model.name()
    );
    let corner = [0.0, 0.0];
    let centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
    let radius = |p: [f64; 2]| (p[0] - centre[0]).hypot(p[1] - centre[1]);
    let (mut worst_d, mut worst_t, mut worst_v) = (0.0f64, 0.0f64, 0.0f64);
    for f in &c.focal {
        let s = LensSetting {
            focal_mm: f.focal_mm,
            f_number: lens.f_number_range[0],
        };
        let g = lens.sensor_mapping(Channel::G, s, w, h);
        // The truth's displacement at sensor point q: sensor radius − ideal radius.
        let truth_disp = |q: [f64; 2]| radius(q) - radius(g.ideal_from_sensor(q));
        let d = f.distortion_fit(c.distortion_model);
        let mut along = 0.0f64;
        for i in 0..=20 {
            let t = f64::from(i) / 20.0;
            let q = [centre[0] * (1.0 - t), centre[1] * (1.0 - t)];
            along = along.max((d.displacement_px(&c.frame, q) - truth_disp(q)).abs());
        }
        let corner_err = (d.corner_displacement_px - truth_disp(corner)).abs();
        worst_d = worst_d.max(along);
        let mut line = format!(
            "{:>5} mm: distortion at the corner {:+.2} px (truth {:+.2}, error {:.3} px, largest along the diagonal {:.3} px), RMS {:.3} px",
            f.focal_mm,
            d.corner_displacement_px,
            truth_disp(corner),
            corner_err,
            along,
            d.rms_px
        );
        if let Some(t) = f.tca_fit(c.tca_model) {
            let rc = radius(g.sensor_from_ideal(g.ideal_from_sensor(corner)));
            let truth = lens.geometry.lateral_colour.map(|m| m * rc);
            let err = (t.red.corner_shift_px - truth[0])
                .abs()
                .max((t.blue.corner_shift_px - truth[1]).abs());
            worst_t = worst_t.max(err);
            line.push_str(&format!(
                "; lateral colour red {:+.3} / blue {:+.3} px (truth {:+.3} / {:+.3}, error {:.3} px)",
                t.red.corner_shift_px, t.blue.corner_shift_px, truth[0], truth[1], err
            ));
        }
        println!("{line}");
    }
    for v in &c.vignetting {
        let g = lens.sensor_mapping(Channel::G, v.setting, w, h);
        let truth_corner = -g.illumination(corner).log2();
        // At the chart's reach along the diagonal.
        let q = [
            centre[0] * (1.0 - v.max_radius),
            centre[1] * (1.0 - v.max_radius),
        ];
        let truth_reach = -g.illumination(q).log2();
        let fit_reach = -v.illumination(v.max_radius).log2();
        worst_v = worst_v.max((fit_reach - truth_reach).abs());
        println!(
            "{:>5} mm f/{:<4.1}: fall-off at the corner {:.3} stops (truth {:.3}, error {:.3}); at the chart's reach r = {:.2}: {:.3} (truth {:.3}, error {:.3}); light gradient {:.3} stops",
            v.setting.focal_mm,
            v.setting.f_number,
            v.corner_stops,
            truth_corner,
            (v.corner_stops - truth_corner).abs(),
            v.max_radius,
            fit_reach,
            truth_reach,
            (fit_reach - truth_reach).abs(),
            v.gradient_stops
        );
    }
    println!(
        "worst: distortion {worst_d:.3} px, lateral colour {worst_t:.3} px, fall-off {worst_v:.3} stops (where the chart reached); {:.0} s in all",
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
