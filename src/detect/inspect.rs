//! What the studio shows for one clicked square: the observed pixels of a channel, the
//! synthetic square the alignment matched them against, and their difference.

use super::SquareAlignment;
use super::filter::gaussian_blur;
use crate::chart::{self, ChartSpec};
use crate::geometry::Homography;
use crate::plane::{Capture, Channel, Plane};

/// Observed, synthetic and residual crops of one square, at the channel plane's own
/// resolution (every other sensor pixel for a CFA plane).
#[derive(Clone, Debug)]
pub struct SquareInspection {
    pub observed: Plane,
    pub synthetic: Plane,
    /// observed − synthetic.
    pub residual: Plane,
    pub residual_rms: f64,
    /// Sensor position of the crop's top-left plane pixel and the plane step.
    pub origin: [f64; 2],
    pub step: usize,
}

/// Sensor pixels of context around the square in the crop.
const MARGIN_PX: f64 = 4.0;

/// Crops of `square` in the first plane of `channel`; `None` when the capture has no
/// such plane or the square falls outside it.
#[must_use]
pub fn inspect_square(
    capture: &Capture,
    square: &SquareAlignment,
    spec: &ChartSpec,
    channel: Channel,
) -> Option<SquareInspection> {
    let cp = capture.planes.iter().find(|p| p.channel == channel)?;
    let xs = square.corners.iter().map(|c| c[0]);
    let ys = square.corners.iter().map(|c| c[1]);
    let x0 = xs.clone().fold(f64::INFINITY, f64::min) - MARGIN_PX;
    let x1 = xs.fold(f64::NEG_INFINITY, f64::max) + MARGIN_PX;
    let y0 = ys.clone().fold(f64::INFINITY, f64::min) - MARGIN_PX;
    let y1 = ys.fold(f64::NEG_INFINITY, f64::max) + MARGIN_PX;
    if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite()) {
        return None;
    }
    let [i0, j0] = cp.plane_from_sensor(x0, y0).map(|v| v.ceil().max(0.0));
    let [i1, j1] = cp.plane_from_sensor(x1, y1).map(|v| v.floor());
    let i1 = i1.min(cp.plane.width as f64 - 1.0);
    let j1 = j1.min(cp.plane.height as f64 - 1.0);
    if i1 < i0 + 2.0 || j1 < j0 + 2.0 || (i1 - i0) > 2000.0 || (j1 - j0) > 2000.0 {
        return None;
    }
    let (i0, j0) = (i0 as usize, j0 as usize);
    let (w, h) = (i1 as usize - i0 + 1, j1 as usize - j0 + 1);
    let observed = cp.plane.crop(i0, j0, w, h);

    // The synthetic square at full sensor resolution over the crop, blurred by the
    // detection's blur estimate, then sampled where this plane has pixels.
    let step = cp.step;
    let origin = cp.sensor_from_plane(i0 as f64, j0 as f64);
    let (sw, sh) = (step * (w - 1) + 1, step * (h - 1) + 1);
    let pad = 8usize;
    let crop_from_chart = Homography::translation(pad as f64 - origin[0], pad as f64 - origin[1])
        .compose(&square.image_from_chart);
    let sharp = chart::rasterize(spec, &crop_from_chart, sw + 2 * pad, sh + 2 * pad, 1.0);
    let sigma = if square.sigma_px.is_finite() && square.sigma_px > 0.0 {
        square.sigma_px
    } else {
        1.0
    };
    let sharp64: Vec<f64> = sharp.data.iter().map(|&v| f64::from(v)).collect();
    let blurred = gaussian_blur(&sharp64, sharp.width, sharp.height, sigma);
    let (black, white) = levels(square, &observed);
    let synthetic = Plane::from_fn(w, h, |i, j| {
        let v = blurred[(pad + step * j) * sharp.width + pad + step * i];
        (black + (white - black) * v) as f32
    });
    let mut residual = Plane::new(w, h);
    let mut ss = 0.0;
    for (k, r) in residual.data.iter_mut().enumerate() {
        *r = observed.data[k] - synthetic.data[k];
        ss += f64::from(*r) * f64::from(*r);
    }
    Some(SquareInspection {
        residual_rms: (ss / (w * h) as f64).sqrt(),
        observed,
        synthetic,
        residual,
        origin,
        step,
    })
}

/// Black and white levels: the detection's histogram peaks when it has them (they are
/// measured on the pooled planes), otherwise the crop's 2nd and 98th percentiles.
fn levels(square: &SquareAlignment, observed: &Plane) -> (f64, f64) {
    let mut v: Vec<f32> = observed.data.clone();
    v.sort_by(f32::total_cmp);
    let q = |p: f64| f64::from(v[((v.len() - 1) as f64 * p).round() as usize]);
    let (lo, hi) = (q(0.02), q(0.98));
    // Per-channel gains differ on a RAW shot, so the crop's own levels are the safer
    // default; the detection's peaks only stand in when the crop is nearly uniform.
    if hi - lo > 1e-3 {
        (lo, hi)
    } else if square.black_level.is_finite() && square.white_level.is_finite() {
        (square.black_level, square.white_level)
    } else {
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::SquareStatus;
    use crate::plane::ChannelPlane;

    /// A square rendered with exactly the model the inspection assumes leaves a residual
    /// far below its contrast.
    #[test]
    fn synthetic_matches_a_rendered_square() {
        let spec = ChartSpec {
            cols: 4,
            rows: 3,
            ..ChartSpec::default()
        };
        let h = Homography::translation(20.0, 20.0).compose(&Homography::scaling(30.0, 30.0));
        let sharp = chart::rasterize(&spec, &h, 180, 150, 1.0);
        let data: Vec<f64> = sharp.data.iter().map(|&v| f64::from(v)).collect();
        let blurred = gaussian_blur(&data, 180, 150, 1.2);
        let plane = Plane::from_fn(180, 150, |x, y| (0.1 + 0.8 * blurred[y * 180 + x]) as f32);
        let capture = Capture {
            width: 180,
            height: 150,
            planes: vec![ChannelPlane {
                channel: Channel::Y,
                plane,
                step: 1,
                offset_x: 0,
                offset_y: 0,
            }],
            setting_focal_mm: None,
            setting_f_number: None,
            setting_focus_m: None,
            identity: Default::default(),
            is_raw: false,
            raw: None,
        };
        let corners = spec.square_corners(1, 1).map(|c| h.apply(c));
        let square = SquareAlignment {
            row: 1,
            col: 1,
            status: SquareStatus::Ok,
            reason: None,
            corners,
            bootstrap_corners: corners,
            image_from_chart: h,
            bootstrap: h,
            residual_rms: 0.0,
            black_level: 0.1,
            white_level: 0.9,
            sigma_px: 1.2,
            sigma_by_channel: vec![(Channel::Y, 1.2)],
            channel_image_from_chart: Vec::new(),
            channel_registration: Vec::new(),
            levels_by_channel: Vec::new(),
        };
        let ins = inspect_square(&capture, &square, &spec, Channel::Y).expect("inside");
        assert!(ins.observed.width >= 30 && ins.observed.height >= 30);
        assert!(ins.residual_rms < 0.02, "rms {}", ins.residual_rms);
        assert!(inspect_square(&capture, &square, &spec, Channel::R).is_none());
    }
}
