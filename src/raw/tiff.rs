//! The TIFF structure lensblur reads itself: a file's first directory (where DNGs and
//! many camera TIFFs keep the raw image and the EXIF settings), what it says of the
//! image there, and a DNG's own colour tags, which win over a decoder's reading of them.

/// Whether a TIFF's first directory is a full-size picture (not a camera's reduced
/// preview, NewSubfileType 1, nor a JPEG-coded preview).
pub(super) fn image_in_ifd0(ifd: &Ifd) -> bool {
    first_tag(ifd, 254).is_none_or(|t| t as u32 & 1 == 0)
        && !matches!(first_tag(ifd, TAG_COMPRESSION), Some(6.0 | 7.0))
}

pub(super) fn first_tag(ifd: &Ifd, tag: u16) -> Option<f64> {
    ifd.get(&tag).and_then(|v| v.first().copied())
}

pub(super) fn is_tiff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*")
}

/// A DNG, or a TIFF holding a CFA image.
pub(super) fn is_raw_ifd(ifd: &Ifd) -> bool {
    ifd.contains_key(&TAG_DNG_VERSION)
        || ifd
            .get(&TAG_PHOTOMETRIC)
            .is_some_and(|v| v.first() == Some(&32803.0))
}

pub(super) const TAG_PHOTOMETRIC: u16 = 262;
pub(super) const TAG_ORIENTATION: u16 = 274;
pub(super) const TAG_DNG_VERSION: u16 = 50706;

/// A TIFF directory's tags as numbers (RATIONALs as quotients), with the byte order.
pub(super) type Ifd = std::collections::HashMap<u16, Vec<f64>>;

/// The first directory of a TIFF (where our DNGs and many others keep the raw image
/// and the EXIF settings). Bounds are checked: a truncated file is an error.
pub(super) fn tiff_ifd0(b: &[u8]) -> Result<Ifd, String> {
    let le = match b.get(0..2) {
        Some(b"II") => true,
        Some(b"MM") => false,
        _ => return Err("not a TIFF".into()),
    };
    let u16_at = |o: usize| -> Result<u16, String> {
        let s = b.get(o..o + 2).ok_or("truncated TIFF")?;
        Ok(if le {
            u16::from_le_bytes([s[0], s[1]])
        } else {
            u16::from_be_bytes([s[0], s[1]])
        })
    };
    let u32_at = |o: usize| -> Result<u32, String> {
        let s = b.get(o..o + 4).ok_or("truncated TIFF")?;
        let a = [s[0], s[1], s[2], s[3]];
        Ok(if le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    };
    let ifd_off = u32_at(4)? as usize;
    let n = u16_at(ifd_off)? as usize;
    let mut out = Ifd::new();
    for e in 0..n {
        let at = ifd_off + 2 + 12 * e;
        let tag = u16_at(at)?;
        let typ = u16_at(at + 2)?;
        let count = u32_at(at + 4)? as usize;
        let size = match typ {
            1 | 2 | 6 | 7 => 1,
            3 | 8 => 2,
            4 | 9 | 11 => 4,
            5 | 10 | 12 => 8,
            _ => continue,
        };
        if count > 1 << 24 {
            return Err(format!("tag {tag}: absurd count {count}"));
        }
        let data = if size * count <= 4 {
            at + 8
        } else {
            u32_at(at + 8)? as usize
        };
        if b.len() < data + size * count {
            return Err(format!("truncated TIFF (tag {tag} points past the end)"));
        }
        let vals: Result<Vec<f64>, String> = (0..count)
            .map(|k| {
                let o = data + k * size;
                Ok(match typ {
                    1 | 2 | 7 => f64::from(b[o]),
                    6 => f64::from(b[o] as i8),
                    3 => f64::from(u16_at(o)?),
                    8 => f64::from(u16_at(o)? as i16),
                    4 => f64::from(u32_at(o)?),
                    9 => f64::from(u32_at(o)? as i32),
                    5 => f64::from(u32_at(o)?) / f64::from(u32_at(o + 4)?.max(1)),
                    10 => f64::from(u32_at(o)? as i32) / f64::from((u32_at(o + 4)? as i32).max(1)),
                    _ => f64::NAN,
                })
            })
            .collect();
        out.insert(tag, vals?);
    }
    Ok(out)
}

pub(super) const TAG_COMPRESSION: u16 = 259;
pub(super) const TAG_STRIP_OFFSETS: u16 = 273;
pub(super) const TAG_ROWS_PER_STRIP: u16 = 278;
pub(super) const TAG_STRIP_BYTE_COUNTS: u16 = 279;
pub(super) const TAG_TILE_OFFSETS: u16 = 324;

/// Whether the first directory holds an uncompressed CFA image that rawloader reads
/// wrongly or not at all: tiles (it refuses them: "Couldn't find tag StripOffsets"), or
/// strips that do not follow one another in the file (it reads every sample on from the
/// first strip, so a gap or a reordering would be read as image).
pub(super) fn needs_own_reader(ifd: &Ifd) -> bool {
    let first = |tag: u16| ifd.get(&tag).and_then(|v| v.first().copied());
    if first(TAG_PHOTOMETRIC) != Some(32803.0) || first(TAG_COMPRESSION) != Some(1.0) {
        return false;
    }
    if ifd.contains_key(&TAG_TILE_OFFSETS) {
        return true;
    }
    match (ifd.get(&TAG_STRIP_OFFSETS), ifd.get(&TAG_STRIP_BYTE_COUNTS)) {
        (Some(offsets), Some(counts)) => offsets
            .windows(2)
            .zip(counts)
            .any(|(o, c)| o[1] != o[0] + c),
        _ => false,
    }
}

/// Per-site black levels of a CFA image in this directory with a 2 × 2 black pattern,
/// in [`RawMeta::site`] order.
pub(super) fn site_black_levels(ifd: &Ifd) -> Option<[f32; 4]> {
    let first = |tag: u16| ifd.get(&tag).and_then(|v| v.first().copied());
    if first(TAG_PHOTOMETRIC) != Some(32803.0) || ifd.get(&50713)? != &vec![2.0, 2.0] {
        return None;
    }
    let b = ifd.get(&50714).filter(|b| b.len() == 4)?;
    b.iter()
        .all(|v| v.is_finite() && (0.0..=65535.0).contains(v))
        .then(|| [b[0] as f32, b[1] as f32, b[2] as f32, b[3] as f32])
}

/// A DNG's XYZ → camera matrix: ColorMatrix2 where there are two (as rawloader picks),
/// else ColorMatrix1; 3 × 3 (a 3-colour sensor's).
pub(super) fn dng_matrix(ifd: &Ifd) -> Option<[[f64; 3]; 3]> {
    ifd.get(&50722)
        .or_else(|| ifd.get(&50721))
        .filter(|m| m.len() == 9 && m.iter().all(|v| v.is_finite()))
        .map(|m| std::array::from_fn(|r| std::array::from_fn(|k| m[3 * r + k])))
}

/// A DNG's AsShotNeutral.
pub(super) fn dng_neutral(ifd: &Ifd) -> Option<[f64; 3]> {
    ifd.get(&50728)
        .filter(|n| n.len() == 3 && n.iter().all(|v| v.is_finite() && *v > 0.0))
        .map(|n| [n[0], n[1], n[2]])
}

/// The EXIF light source of the colour matrix a DNG reader uses: rawloader (and we)
/// take ColorMatrix2 where there are two (usually D65), ColorMatrix1 otherwise; D65
/// where the file does not say (a camera RAW, whose matrix is rawloader's D65 one).
pub(super) fn matrix_illuminant(ifd: &Ifd) -> u16 {
    let tag = if ifd.contains_key(&50722) {
        50779
    } else {
        50778
    };
    ifd.get(&tag)
        .and_then(|v| v.first().copied())
        .filter(|v| (1.0..=255.0).contains(v))
        .map_or(21, |v| v as u16)
}
