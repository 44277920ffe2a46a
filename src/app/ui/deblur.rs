//! The Deblur view: a photo, a region of it deblurred with the Gaussians the profile
//! predicts and with the kernels measured at the photo's setting (the paper's
//! Fig. 7–8), side by side or with a slider, and export of the whole photo. Hovering
//! the compared region shows a loupe of the same pixels before and after, and their
//! values in both.

use super::super::{
    Command, DeblurLayout, DeblurResult, DeblurState, DeblurZoom, ShotViewState, ViewerContext,
    ViewerState,
};
use super::Frame;
use crate::app::jobs::JobKind;
use crate::app::{DeblurCommand, DialogCommand, ViewCommand};
use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2};

/// What the Deblur view draws from: its own state, the photo's session and profile, the
/// shot selected (the photo it can open) and the viewer's developed-or-linear switch.
pub(super) struct DeblurContext<'a> {
    cx: ViewerContext<'a>,
    state: &'a DeblurState,
    shot: &'a ShotViewState,
    /// A preview is being deblurred.
    previewing: bool,
    /// The view's method: its own, else the session's.
    method: crate::deblur::Method,
}

impl<'a> DeblurContext<'a> {
    pub(super) fn of(f: &Frame<'a>) -> Self {
        Self {
            cx: f.cx,
            state: &f.views.deblur,
            shot: &f.views.shot,
            previewing: f.jobs.is_running(JobKind::DeblurPreview),
            method: f.deblur_method,
        }
    }
}

pub(super) fn deblur_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.heading("Deblur");
    toolbar_ui(d, out, ui);
    let has_place = d.cx.profile().is_some_and(|(_, p)| p.place.is_some());
    super::deblur_controls::controls_ui(d.state, (d.method, has_place), out, ui);
    let Some(photo) = &d.state.photo else {
        ui.label("No photo open. Open one, drop one on this view, or deblur the selected shot of the session.");
        return;
    };
    let (width, height) = (photo.capture.width, photo.capture.height);
    let shown = d.cx.shown_path(&photo.path);
    let mut f = photo.focal_mm.unwrap_or(0.0);
    let mut a = photo.f_number.unwrap_or(0.0);
    // Where the photo was focused, as its file says: the core judges it against the
    // profile's focus range.
    let photo_focus_m = photo.capture.setting_focus_m;
    ui.horizontal(|ui| {
        ui.label(format!("{shown} — {width} × {height} px"));
        ui.separator();
        let (rf, ra) = super::setting_drag_values(
            ui,
            (&mut f, &mut a),
            [
                "focal length, mm: from EXIF, else the session's record of this file; drag or type",
                "aperture, f-number",
            ],
        );
        if rf.drag_stopped() || ra.drag_stopped() || rf.lost_focus() || ra.lost_focus() {
            let centre = d
                .state
                .comparison
                .as_ref()
                .map_or([width as f64 / 2.0, height as f64 / 2.0], |c| {
                    c.comparison.region.centre()
                });
            out.push(Command::Deblur(DeblurCommand::SetPhotoSetting {
                focal_mm: (f > 0.0).then_some(f),
                f_number: (a > 0.0).then_some(a),
            }));
            out.push(Command::Deblur(DeblurCommand::DeblurAt(centre)));
        } else if rf.changed() || ra.changed() {
            out.push(Command::Deblur(DeblurCommand::SetPhotoSetting {
                focal_mm: (f > 0.0).then_some(f),
                f_number: (a > 0.0).then_some(a),
            }));
        }
    });
    // Where the profile is less well trusted at this setting and focus: the core's own
    // words, as `lensblur deblur` prints them.
    if let Some((_, profile)) = d.cx.profile()
        && f > 0.0
        && a > 0.0
        && let Some(line) = profile.trust_line(
            crate::plane::LensSetting {
                focal_mm: f,
                f_number: a,
            },
            photo_focus_m,
            None,
        )
    {
        ui.colored_label(ui.visuals().warn_fg_color, line);
    }
    // A developed JPEG with a RAW profile, or the other way round: the core's warning,
    // as `lensblur deblur` prints it.
    if let Some((path, profile)) = d.cx.profile()
        && let Some(w) = profile.picture_warning(photo.kind, &shown, &d.cx.shown_path(path))
    {
        ui.colored_label(ui.visuals().warn_fg_color, format!("warning: {w}"));
    }
    let overview_open = d.state.overview_open;
    let header = egui::CollapsingHeader::new("The whole photo (click it to choose the region)")
        .id_salt("deblur overview")
        .open(Some(overview_open))
        .show(ui, |ui| overview_and_notes_ui(d, out, ui));
    if header.header_response.clicked() {
        out.push(Command::Deblur(DeblurCommand::SetDeblurOverview(
            !overview_open,
        )));
    }
    ui.separator();
    match (&d.state.comparison, d.state.layout) {
        (None, _) => {
            ui.label("Click the photo to deblur a region.");
        }
        (Some(_), DeblurLayout::SideBySide) => side_by_side_ui(d, out, ui),
        (Some(_), DeblurLayout::Slider) => slider_ui(d, out, ui),
    }
}

/// The view's buttons: open a photo or the selected shot, the layout, developed or
/// linear, and export.
fn toolbar_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        if ui
            .button("Open photo…")
            .on_hover_text("A photo taken with the calibrated lens: RAW, DNG, TIFF, PNG or JPEG; its settings come from EXIF (Ctrl+P, or drop it on this view)")
            .clicked()
        {
            out.push(Command::Dialog(DialogCommand::OpenPhotoDialog));
        }
        let shot = d
            .shot.selected
            .and_then(|id| {
                let s = d.cx.session()?;
                Some((id, s.path_of(s.shot(id)?)))
            });
        if let Some((_, path)) = shot
            && ui
                .button("Deblur the selected shot")
                .on_hover_text("Open the shot selected in the session panel as the photo: its own measured kernels are then the comparison")
                .clicked()
        {
            out.push(Command::Deblur(DeblurCommand::OpenPhoto(path)));
        }
        ui.separator();
        for (layout, label) in [
            (DeblurLayout::SideBySide, "Side by side"),
            (DeblurLayout::Slider, "Slider"),
        ] {
            if ui
                .selectable_label(d.state.layout == layout, label)
                .clicked()
            {
                out.push(Command::Deblur(DeblurCommand::SetDeblurLayout(layout)));
            }
        }
        if d
            .state
            .photo
            .as_ref()
            .is_some_and(|p| p.developed.is_some())
        {
            ui.separator();
            let mut developed = d.shot.viewer.developed;
            if ui
                .checkbox(&mut developed, "developed")
                .on_hover_text("The RAW photo and its crops as a RAW editor shows them (imagepipe); off: linear camera RGB, as deblurred")
                .changed()
            {
                out.push(Command::View(ViewCommand::SetViewer(ViewerState {
                    developed,
                    ..d.shot.viewer
                })));
            }
        }
        ui.separator();
        ui.menu_button("Export…", |ui| {
            for r in [DeblurResult::Predicted, DeblurResult::Measured] {
                if ui
                    .add_enabled(
                        d.state.photo.is_some(),
                        egui::Button::new(format!("whole photo deblurred with {}", r.label())),
                    )
                    .on_hover_text("Deblur the open photo and write it: a RAW photo as a DNG with its metadata (or TIFF/PNG), others as 16-bit linear TIFF or PNG (Ctrl+E: predicted)")
                    .clicked()
                {
                    out.push(Command::Dialog(DialogCommand::ExportDeblurDialog(r)));
                    ui.close();
                }
            }
            ui.separator();
            for (dng, label) in [
                (false, "a set of photos (16-bit TIFF)…"),
                (true, "a set of RAW photos (DNG)…"),
            ] {
                if ui
                    .add_enabled(d.cx.profile().is_some(), egui::Button::new(label))
                    .on_hover_text("Each photo deblurred with the profile at its own focal length and aperture (from EXIF); photos of another camera or lens, or outside the calibrated range, are skipped with the reason")
                    .clicked()
                {
                    out.push(Command::Dialog(DialogCommand::ExportPhotosDialog { dng }));
                    ui.close();
                }
            }
        })
        .response
        .on_hover_text("Write the open photo deblurred, or a set of photos");
    });
}

/// The whole photo with the region outlined, and what the panes below compare.
fn overview_and_notes_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    ui.horizontal_top(|ui| {
        let overview_w = 280.0;
        ui.vertical(|ui| {
            ui.set_width(overview_w);
            overview_ui(d, out, ui, overview_w);
        });
        ui.vertical(|ui| {
            ui.label("Click the photo to choose the region compared below (outlined).");
            if let Some(c) = &d.state.comparison {
                let r = c.comparison.region;
                ui.label(format!(
                    "Region x {}–{}, y {}–{} px.",
                    r.x0,
                    r.x0 + r.width,
                    r.y0,
                    r.y0 + r.height
                ));
            }
            ui.label("Predicted Gaussians: the profile's model at the photo's focal length and aperture (what deblurring any photo uses).");
            ui.label("Measured kernels: the non-parametric kernels measured on the session's chart shot at the same setting (the paper's Fig. 7–8 comparison).");
            if d.previewing {
                ui.label("Deblurring…");
            }
        });
    });
}

/// The whole photo at a small scale with the compared region outlined: the navigator;
/// a click moves the region there.
fn overview_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui, width: f32) {
    let Some(photo) = &d.state.photo else {
        return;
    };
    let cap = &photo.capture;
    let scale = width / cap.width as f32;
    let size = Vec2::new(width, cap.height as f32 * scale);
    let (rect, response) = ui.allocate_exact_size(size, Sense::click());
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "photo overview"));
    let painter = ui.painter_at(rect);
    match photo.shown(d.shot.viewer.developed) {
        Some(t) => {
            painter.image(
                t.id(),
                rect,
                Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                Color32::WHITE,
            );
        }
        None => {
            painter.rect_filled(rect, 0.0, super::image_backdrop(ui));
        }
    }
    if let Some(c) = &d.state.comparison {
        let r = c.comparison.region;
        let min = rect.min + Vec2::new(r.x0 as f32, r.y0 as f32) * scale;
        let region = Rect::from_min_size(min, Vec2::new(r.width as f32, r.height as f32) * scale);
        painter.rect_stroke(
            region,
            0.0,
            Stroke::new(2.0, Color32::from_rgb(255, 210, 0)),
            egui::StrokeKind::Outside,
        );
    }
    if response.clicked()
        && let Some(p) = response.interact_pointer_pos()
    {
        let d = (p - rect.min) / scale;
        out.push(Command::Deblur(DeblurCommand::DeblurAt([
            f64::from(d.x),
            f64::from(d.y),
        ])));
    }
}

fn titles(d: &DeblurContext<'_>) -> [String; 3] {
    let setting = d
        .state
        .photo
        .as_ref()
        .and_then(super::super::Photo::setting)
        .map_or_else(String::new, |s| {
            format!(" at {:.0} mm f/{:.1}", s.focal_mm, s.f_number)
        });
    let from = d
        .state
        .comparison
        .as_ref()
        .and_then(|c| c.measured_from.clone())
        .map_or_else(String::new, |n| format!(" (from {n})"));
    [
        "original".to_owned(),
        format!("deblurred: predicted Gaussians{setting}"),
        format!("deblurred: measured kernels{from}"),
    ]
}

/// The room left on screen: long labels above can make the panel wider than the window,
/// and panes sized to that would run off its edge.
fn visible_size(ui: &egui::Ui) -> Vec2 {
    let avail = ui.available_size();
    let right = ui.clip_rect().right() - ui.cursor().left();
    Vec2::new(avail.x.min(right), avail.y)
}

/// How many screen points one region pixel takes in the panes: `None` at Fit.
fn points_per_pixel(d: &DeblurContext<'_>, ui: &egui::Ui) -> Option<f32> {
    match d.state.zoom {
        DeblurZoom::Fit => None,
        DeblurZoom::Times(z) => Some(f32::from(z) / ui.ctx().pixels_per_point()),
    }
}

/// At a zoom, the region the panes hold: asked for when the layout changes it. Its
/// height comes from the window, not from the room left this frame: the status area
/// grows and shrinks as previews start and end, and a region that followed it would
/// start a new preview each time one started.
fn request_viewport(
    d: &DeblurContext<'_>,
    out: &mut Vec<Command>,
    ui: &egui::Ui,
    pane: Vec2,
    per_px: Option<f32>,
) {
    if let Some(pp) = per_px {
        let tall = ui.ctx().content_rect().height() * 0.6;
        let v = [
            ((pane.x / pp) as usize).max(16),
            ((tall / pp) as usize).max(16),
        ];
        if d.state.viewport != Some(v) {
            out.push(Command::Deblur(DeblurCommand::SetDeblurViewport(v)));
        }
    }
}

/// One compared pane: the texture at the zoom (or fitted), shifted by a drag in
/// progress; dragging it pans every pane at once. Returns, while the pointer is over the
/// image and not dragging, where it is: on screen, on the texture (0–1) and the
/// screen points per texel.
fn pane_ui(
    d: &DeblurContext<'_>,
    out: &mut Vec<Command>,
    ui: &mut egui::Ui,
    texture: &egui::TextureHandle,
    size: Vec2,
    per_px: Option<f32>,
    label: &str,
) -> Option<(Pos2, Pos2, f32)> {
    let (rect, response) = ui.allocate_exact_size(size, Sense::drag());
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, label));
    let tex = texture.size_vec2();
    let scale = per_px.unwrap_or_else(|| (size.x / tex.x).min(size.y / tex.y));
    let shift = Vec2::new(d.state.drag[0], d.state.drag[1]) * scale;
    let shown = Rect::from_center_size(rect.center() + shift, tex * scale);
    let painter = ui.painter_at(rect);
    painter.image(
        texture.id(),
        shown,
        Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
        Color32::WHITE,
    );
    if response.dragged() {
        let d = response.drag_delta() / scale;
        out.push(Command::Deblur(DeblurCommand::DragDeblur([d.x, d.y])));
    }
    if response.drag_stopped() {
        out.push(Command::Deblur(DeblurCommand::EndDragDeblur));
    }
    hovered_texel(&response, shown, scale)
}

/// Where the pointer is over an image drawn in `shown` at `scale` points per texel:
/// on screen and in the image's 0–1 coordinates; `None` off it or while dragging.
fn hovered_texel(response: &egui::Response, shown: Rect, scale: f32) -> Option<(Pos2, Pos2, f32)> {
    if response.dragged() {
        return None;
    }
    let p = response.hover_pos()?;
    let uv = Pos2::new(
        (p.x - shown.left()) / shown.width(),
        (p.y - shown.top()) / shown.height(),
    );
    ((0.0..1.0).contains(&uv.x) && (0.0..1.0).contains(&uv.y)).then_some((p, uv, scale))
}

/// The planes behind pane `k` of the comparison (0 original, 1 predicted, 2 measured).
fn plane_set(
    c: &crate::review::DeblurComparison,
    k: usize,
) -> Option<&[(crate::plane::Channel, crate::plane::Plane)]> {
    match k {
        0 => Some(&c.original),
        1 => c.predicted.as_ref().ok().map(Vec::as_slice),
        _ => c.measured.as_ref().ok().map(Vec::as_slice),
    }
}

/// Side of each half of the loupe, points.
const LOUPE_SIDE: f32 = 150.0;

/// The loupe beside the pointer: the same photo pixels around it before (left) and
/// after (right), at twice the panes' magnification and at least one photo pixel per
/// screen pixel, with both images' linear values at the pointer below.
fn loupe_ui(
    ui: &egui::Ui,
    pointer: Pos2,
    uv: Pos2,
    scale: f32,
    [before, after]: [&egui::TextureHandle; 2],
    planes: [Option<&[(crate::plane::Channel, crate::plane::Plane)]>; 2],
) {
    let magnification = (2.0 * scale).max(1.0 / ui.ctx().pixels_per_point());
    let tex = before.size_vec2();
    // The loupe's window on the texture, in 0–1 units.
    let half = Vec2::new(
        LOUPE_SIDE / 2.0 / magnification / tex.x,
        LOUPE_SIDE / 2.0 / magnification / tex.y,
    );
    let uv_rect = Rect::from_center_size(uv, half * 2.0);
    let screen = ui.ctx().content_rect();
    // Right of and below the pointer, or flipped where the window ends.
    // The loupe with its frame and the two lines of values under it.
    let size = Vec2::new(2.0 * LOUPE_SIDE + 20.0, LOUPE_SIDE + 76.0);
    let mut min = pointer + Vec2::new(24.0, 24.0);
    if min.x + size.x > screen.right() {
        min.x = pointer.x - 24.0 - size.x;
    }
    if min.y + size.y > screen.bottom() {
        min.y = pointer.y - 24.0 - size.y;
    }
    let values = |set: Option<&[(crate::plane::Channel, crate::plane::Plane)]>| {
        set.map_or_else(
            || "none".to_owned(),
            |planes| {
                planes
                    .iter()
                    .map(|(ch, p)| {
                        let x = ((uv.x * p.width as f32) as usize).min(p.width.saturating_sub(1));
                        let y = ((uv.y * p.height as f32) as usize).min(p.height.saturating_sub(1));
                        format!("{} {:.3}", ch.name(), p.get(x, y))
                    })
                    .collect::<Vec<_>>()
                    .join("  ")
            },
        )
    };
    // An area, not a bare painter, so the values are text a screen reader finds.
    egui::Area::new(egui::Id::unique("deblur loupe"))
        .order(egui::Order::Tooltip)
        .fixed_pos(min)
        .interactable(false)
        .show(ui.ctx(), |ui| {
            egui::Frame::popup(ui.style()).show(ui, |ui| {
                let (row, _) = ui.allocate_exact_size(
                    Vec2::new(2.0 * LOUPE_SIDE + 4.0, LOUPE_SIDE),
                    Sense::hover(),
                );
                let painter = ui.painter_at(row);
                for (k, (texture, label)) in [(before, "before"), (after, "after")]
                    .into_iter()
                    .enumerate()
                {
                    let r = Rect::from_min_size(
                        row.min + Vec2::new(k as f32 * (LOUPE_SIDE + 4.0), 0.0),
                        Vec2::splat(LOUPE_SIDE),
                    );
                    painter
                        .with_clip_rect(r)
                        .image(texture.id(), r, uv_rect, Color32::WHITE);
                    super::caption(
                        &painter,
                        r.left_top() + Vec2::new(4.0, 4.0),
                        egui::Align2::LEFT_TOP,
                        label.into(),
                    );
                    // The pixel under the pointer, marked at the loupe's centre.
                    painter.rect_stroke(
                        Rect::from_center_size(r.center(), Vec2::splat(magnification.max(3.0))),
                        0.0,
                        Stroke::new(1.0, Color32::from_rgb(255, 210, 0)),
                        egui::StrokeKind::Outside,
                    );
                }
                ui.label(
                    egui::RichText::new(format!(
                        "before {}\nafter  {}",
                        values(planes[0]),
                        values(planes[1])
                    ))
                    .monospace()
                    .size(11.0),
                );
                ui.weak(format!(
                    "loupe {magnification:.1}× · linear values at the pointer"
                ));
            });
        });
}

fn side_by_side_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let Some(view) = &d.state.comparison else {
        return;
    };
    let c = view.comparison.clone();
    let reasons = [
        None,
        c.predicted.as_ref().err().cloned(),
        c.measured.as_ref().err().cloned(),
    ];
    let shown = view.shown(d.shot.viewer.developed).clone();
    let titles = titles(d);
    let avail = visible_size(ui);
    let per_px = points_per_pixel(d, ui);
    let pane = match per_px {
        None => Vec2::splat(((avail.x - 24.0) / 3.0).min(avail.y - 40.0).max(64.0)),
        Some(_) => Vec2::new(
            ((avail.x - 24.0) / 3.0).max(64.0),
            (avail.y - 40.0).max(64.0),
        ),
    };
    request_viewport(d, out, ui, pane, per_px);
    ui.horizontal_top(|ui| {
        for k in 0..3 {
            ui.vertical(|ui| {
                ui.set_width(pane.x);
                // Whole, on a second line where the pane is narrow: a cut title hides which
                // result the pane shows.
                ui.add(egui::Label::new(&titles[k]).wrap());
                match (&shown[k], &reasons[k]) {
                    (Some(t), _) => {
                        let hover = pane_ui(d, out, ui, t, pane, per_px, &titles[k]);
                        // Before and after: the original and this pane's result (the
                        // predicted one under the original's pane).
                        let after = if k == 0 { 1 } else { k };
                        if let (Some((pointer, uv, scale)), Some(before), Some(result)) =
                            (hover, &shown[0], &shown[after])
                        {
                            let planes = [Some(&c.original[..]), plane_set(&c, after)];
                            loupe_ui(ui, pointer, uv, scale, [before, result], planes);
                        }
                    }
                    (None, Some(reason)) => {
                        let (rect, _) = ui.allocate_exact_size(pane, Sense::hover());
                        ui.painter().rect_stroke(
                            rect,
                            2.0,
                            Stroke::new(1.0, ui.visuals().weak_text_color()),
                            egui::StrokeKind::Inside,
                        );
                        ui.put(
                            rect.shrink(8.0),
                            egui::Label::new(
                                egui::RichText::new(reason).color(ui.visuals().warn_fg_color),
                            )
                            .wrap(),
                        );
                    }
                    (None, None) => {
                        ui.label("no image");
                    }
                }
            });
        }
    });
}

/// One crop: the original left of the divider, the chosen result right of it; drag to
/// move the divider.
fn slider_ui(d: &DeblurContext<'_>, out: &mut Vec<Command>, ui: &mut egui::Ui) {
    let titles = titles(d);
    // The region follows the pane even while a result is missing, so a result that
    // arrives later is already the pane's size.
    let per_px = points_per_pixel(d, ui);
    let early = (visible_size(ui) - Vec2::new(8.0, 40.0)).max(Vec2::splat(64.0));
    request_viewport(d, out, ui, early, per_px);
    let Some(view) = &d.state.comparison else {
        return;
    };
    ui.horizontal(|ui| {
        ui.label("right of the divider (pan: click the overview):");
        for (r, k) in [(DeblurResult::Predicted, 1), (DeblurResult::Measured, 2)] {
            if ui
                .selectable_label(d.state.slider_result == r, &titles[k])
                .clicked()
            {
                out.push(Command::Deblur(DeblurCommand::SetSliderResult(r)));
            }
        }
    });
    let k = match d.state.slider_result {
        DeblurResult::Predicted => 1,
        DeblurResult::Measured => 2,
    };
    let shown = view.shown(d.shot.viewer.developed);
    let (Some(original), result) = (&shown[0], &shown[k]) else {
        return;
    };
    let Some(result) = result else {
        let reason = match d.state.slider_result {
            DeblurResult::Predicted => view.comparison.predicted.as_ref().err(),
            DeblurResult::Measured => view.comparison.measured.as_ref().err(),
        };
        ui.colored_label(
            ui.visuals().warn_fg_color,
            reason.map_or("no result", String::as_str),
        );
        return;
    };
    let avail = visible_size(ui);
    let size = original.size_vec2();
    let (pane, scale) = match per_px {
        None => {
            let fit = ((avail.x - 8.0) / size.x)
                .min((avail.y - 8.0) / size.y)
                .max(0.1);
            (size * fit, fit)
        }
        Some(pp) => ((avail - Vec2::splat(8.0)).max(Vec2::splat(64.0)), pp),
    };
    let (original, result) = (original.clone(), result.clone());
    let comparison = view.comparison.clone();
    let (rect, response) = ui.allocate_exact_size(pane, Sense::click_and_drag());
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, "divider"));
    let mut t = d.state.slider;
    if (response.dragged() || response.clicked())
        && let Some(p) = response.interact_pointer_pos()
    {
        t = ((p.x - rect.left()) / rect.width()).clamp(0.0, 1.0);
        out.push(Command::Deblur(DeblurCommand::SetSlider(t)));
    }
    let split = rect.left() + t * rect.width();
    let painter = ui.painter_at(rect);
    // Both crops at the same place and scale, each clipped to its side of the divider.
    let shown = Rect::from_center_size(rect.center(), size * scale);
    let full = Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0));
    painter
        .with_clip_rect(Rect::from_min_max(
            rect.min,
            Pos2::new(split, rect.bottom()),
        ))
        .image(original.id(), shown, full, Color32::WHITE);
    painter
        .with_clip_rect(Rect::from_min_max(Pos2::new(split, rect.top()), rect.max))
        .image(result.id(), shown, full, Color32::WHITE);
    painter.line_segment(
        [
            Pos2::new(split, rect.top()),
            Pos2::new(split, rect.bottom()),
        ],
        Stroke::new(2.0, Color32::from_rgb(255, 210, 0)),
    );
    super::caption(
        &painter,
        rect.left_top() + Vec2::new(6.0, 6.0),
        egui::Align2::LEFT_TOP,
        "original".into(),
    );
    super::caption(
        &painter,
        rect.right_top() + Vec2::new(-6.0, 6.0),
        egui::Align2::RIGHT_TOP,
        d.state.slider_result.label().into(),
    );
    if let Some((pointer, uv, scale)) = hovered_texel(&response, shown, scale) {
        let c = &comparison;
        loupe_ui(
            ui,
            pointer,
            uv,
            scale,
            [&original, &result],
            [Some(&c.original[..]), plane_set(c, k)],
        );
    }
}
