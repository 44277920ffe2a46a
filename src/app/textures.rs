//! Textures of linear planes and developed images, for the shot previews, the photo,
//! the deblurred crops (made in `logic`) and the inspector's crops (`view_data`).

use crate::develop::Developed;
use crate::plane::{Capture, Channel, ChannelPlane, Plane};

/// Display value of a linear sample: sRGB-like encoding so mid-greys look right.
pub(crate) fn encode(v: f32) -> u8 {
    (crate::plane::srgb_encode(v.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8
}

/// A grey texture of one channel (the pooled grey when `channel` is `None`) at its
/// plane's own resolution.
pub(crate) fn channel_texture(
    ctx: &egui::Context,
    name: &str,
    capture: &Capture,
    channel: Option<Channel>,
) -> Option<egui::TextureHandle> {
    let plane: Plane = match channel {
        Some(c) => pooled_plane(capture, c)?.plane,
        None => capture.grey(),
    };
    let img = egui::ColorImage::from_gray_iter(
        [plane.width, plane.height],
        plane.data.iter().map(|&v| encode(v)),
    );
    Some(ctx.load_texture(name, img, egui::TextureOptions::NEAREST))
}

/// A colour texture of full-resolution planes (R, G, B; a lone plane as grey), each
/// plane's linear values divided by its white (default: the planes' own display whites).
pub(crate) fn rgb_texture(
    ctx: &egui::Context,
    name: &str,
    planes: &[(Channel, Plane)],
    whites: Option<&[(Channel, f32)]>,
) -> Option<egui::TextureHandle> {
    let first = &planes.first()?.1;
    let (w, h) = (first.width, first.height);
    if w == 0 || h == 0 {
        return None;
    }
    let own;
    let whites = match whites {
        Some(w) => w,
        None => {
            own = crate::review::display_whites(planes);
            &own
        }
    };
    let white_of = |c: Channel| {
        whites
            .iter()
            .find(|(ch, _)| *ch == c)
            .map_or(1.0, |(_, v)| *v)
    };
    let get = |c: Channel| {
        planes
            .iter()
            .find(|(ch, _)| *ch == c)
            .map(|(_, p)| (p, white_of(c)))
    };
    let first = (first, white_of(planes[0].0));
    let [r, g, b] = match (get(Channel::R), get(Channel::G), get(Channel::B)) {
        (Some(r), Some(g), Some(b)) => [r, g, b],
        _ => [first, first, first],
    };
    let pixels: Vec<egui::Color32> = (0..w * h)
        .map(|k| {
            let v =
                |(p, white): (&Plane, f32)| encode(p.data.get(k).copied().unwrap_or(0.0) / white);
            egui::Color32::from_rgb(v(r), v(g), v(b))
        })
        .collect();
    let img = egui::ColorImage {
        size: [w, h],
        source_size: egui::Vec2::new(w as f32, h as f32),
        pixels,
    };
    Some(ctx.load_texture(name, img, egui::TextureOptions::NEAREST))
}

/// The first plane of a channel (G1 for a Bayer G): enough for display.
fn pooled_plane(capture: &Capture, channel: Channel) -> Option<ChannelPlane> {
    capture
        .planes
        .iter()
        .find(|p| p.channel == channel)
        .cloned()
}

/// A texture of a developed (8-bit sRGB) image.
pub(crate) fn developed_texture(
    ctx: &egui::Context,
    name: &str,
    image: &Developed,
) -> egui::TextureHandle {
    let img = egui::ColorImage::from_rgb([image.width, image.height], &image.rgb);
    ctx.load_texture(name, img, egui::TextureOptions::NEAREST)
}
