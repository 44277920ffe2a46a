//! The largest inputs lensblur accepts, in one place (docs/formats.md, "Limits").
//!
//! Each limit is checked before the allocation it bounds, from the numbers a file
//! declares (a header's width and height, a file's length, a profile's orders), so a
//! corrupt or hostile file is refused with its numbers instead of exhausting memory.
//! The sizes are set for a 24 GiB machine: a 100 MP 16-bit photo is well inside them.

/// Largest image side, in pixels (sensors today are below 20 000).
pub const MAX_IMAGE_SIDE: usize = 100_000;
/// Smallest image side worth loading.
pub const MIN_IMAGE_SIDE: usize = 16;
/// Largest image, in pixels: 300 MP (pixel-shift composites of 100 MP sensors reach
/// 400 MP; past this the linear planes alone take over 3.6 GB).
pub const MAX_IMAGE_PIXELS: usize = 300_000_000;
/// Largest image file read into memory: 300 MP of 16-bit RGB with room for headers.
pub const MAX_IMAGE_FILE_BYTES: u64 = 2 << 30;
/// Largest JSON file lensblur reads (a profile of a dense local model is a few MB, a
/// kernels file with 3× kernel arrays of a 50 MP chart shot about 100 MB).
pub const MAX_JSON_BYTES: u64 = 512 << 20;
/// Largest kernel radius in photo pixels. The paper's lenses stay under 10 px; a wider
/// kernel is a focusing error, not lens blur.
pub const MAX_KERNEL_RADIUS_PX: f64 = 64.0;
/// Largest oversampling of a stored kernel (3 is what `lensblur kernels` writes).
pub const MAX_OVERSAMPLE: usize = 9;
/// Largest side of a stored kernel array: the widest kernel at the finest sampling.
pub const MAX_KERNEL_SIDE: usize = 2 * (MAX_KERNEL_RADIUS_PX as usize) * MAX_OVERSAMPLE + 1;
/// Largest polynomial order of a model's terms in (f, a) (α) and (x, y) (β).
pub const MAX_MODEL_ORDER: usize = 15;
/// Largest side of a profile's sensor.
pub const MAX_SENSOR_SIDE_PX: usize = 1 << 17;
/// Most centres of a local model's grid.
pub const MAX_LOCAL_CENTRES: usize = 1_000_000;
/// Most shots in one session or manifest: a lens calibrated at every focal length and
/// aperture of a zoom with a few repeats is a few hundred.
pub const MAX_SESSION_SHOTS: usize = 10_000;

/// Whether an image of `width × height` is within the side and pixel limits; the
/// reason, with its numbers, when not.
///
/// # Errors
/// The image is too small, too large on a side, or has too many pixels.
pub fn check_image_size(width: usize, height: usize) -> Result<(), String> {
    let sides = MIN_IMAGE_SIDE..=MAX_IMAGE_SIDE;
    if !sides.contains(&width) || !sides.contains(&height) {
        return Err(format!(
            "image size {width} × {height}: each side must be {MIN_IMAGE_SIDE}–{MAX_IMAGE_SIDE} px"
        ));
    }
    let pixels = width.saturating_mul(height);
    if pixels > MAX_IMAGE_PIXELS {
        return Err(format!(
            "image size {width} × {height} = {:.0} MP is above the limit of {:.0} MP",
            pixels as f64 / 1e6,
            MAX_IMAGE_PIXELS as f64 / 1e6
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_sizes_at_and_past_each_limit() {
        assert!(check_image_size(MIN_IMAGE_SIDE, MIN_IMAGE_SIDE).is_ok());
        assert!(check_image_size(MIN_IMAGE_SIDE - 1, 100).is_err());
        assert!(check_image_size(MAX_IMAGE_SIDE, 3000).is_ok());
        assert!(check_image_size(MAX_IMAGE_SIDE + 1, 100).is_err());
        // 100 MP in, 20 000 × 20 000 = 400 MP out, with its numbers.
        assert!(check_image_size(12_000, 8_400).is_ok());
        let e = check_image_size(20_000, 20_000).unwrap_err();
        assert!(e.contains("400 MP") && e.contains("300 MP"), "{e}");
        // No overflow on absurd sides.
        assert!(check_image_size(usize::MAX, usize::MAX).is_err());
    }
}
