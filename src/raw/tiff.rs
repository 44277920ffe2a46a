//! The TIFF structure lensblur reads itself: a file's first directory (where DNGs and
//! many camera TIFFs keep the raw image and the EXIF settings), what it says of the
//! image there, a DNG's own colour tags, which win over a decoder's reading of them, and
//! where a cut-short TIFF ends.

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

/// A TIFF's bytes and byte order: the one reader of TIFF structure here, for the first
/// directory's tags ([`tiff_ifd0`]) and for where a cut file ends ([`where_cut`]).
struct Tiff<'a> {
    b: &'a [u8],
    le: bool,
}

/// One tag of a directory: its type's size in bytes, its count, and where its values
/// lie in the file.
struct Entry {
    tag: u16,
    typ: u16,
    size: u64,
    count: u64,
    data: u64,
}

impl<'a> Tiff<'a> {
    /// The TIFF whose header is at byte `base` of `b` (a camera's TIFF-based RAW: TIFF's
    /// 42, Panasonic's 0x55, Olympus's "RO" and "SR"), and where its first directory is.
    fn open(b: &'a [u8], base: u64) -> Option<(Self, u64)> {
        let le = match b.get(usize::try_from(base).ok()?..)?.get(..2)? {
            b"II" => true,
            b"MM" => false,
            _ => return None,
        };
        let t = Self { b, le };
        if !matches!(t.u16(base + 2)?, 42 | 0x55 | 0x4F52 | 0x5352) {
            return None;
        }
        let first = base + u64::from(t.u32(base + 4)?);
        Some((t, first))
    }

    fn len(&self) -> u64 {
        self.b.len() as u64
    }

    fn bytes<const N: usize>(&self, o: u64) -> Option<[u8; N]> {
        let o = usize::try_from(o).ok()?;
        self.b.get(o..o.checked_add(N)?)?.try_into().ok()
    }

    fn u16(&self, o: u64) -> Option<u16> {
        let a = self.bytes(o)?;
        Some(if self.le {
            u16::from_le_bytes(a)
        } else {
            u16::from_be_bytes(a)
        })
    }

    fn u32(&self, o: u64) -> Option<u32> {
        let a = self.bytes(o)?;
        Some(if self.le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    }

    /// The directory at byte `at` (its offsets counted from `base`): its entries of a
    /// type TIFF defines, and the link to the next directory (0: none). Where the file
    /// ends first, where it was cut.
    fn directory(&self, at: u64, base: u64) -> Result<(Vec<Entry>, u64), String> {
        let len = self.len();
        let n = self
            .u16(at)
            .ok_or_else(|| format!("truncated at byte {len}: a directory starts at byte {at}"))?;
        let end = at + 2 + 12 * u64::from(n);
        if end > len {
            return Err(truncated(len, "a directory", end));
        }
        let mut entries = Vec::with_capacity(usize::from(n));
        for k in 0..u64::from(n) {
            let e = at + 2 + 12 * k;
            let (tag, typ, count) = (
                self.u16(e).unwrap_or(0),
                self.u16(e + 2).unwrap_or(0),
                u64::from(self.u32(e + 4).unwrap_or(0)),
            );
            let size = match typ {
                1 | 2 | 6 | 7 => 1,
                3 | 8 => 2,
                4 | 9 | 11 | 13 => 4,
                5 | 10 | 12 => 8,
                _ => continue,
            };
            let data = if size * count <= 4 {
                e + 8
            } else {
                base + u64::from(self.u32(e + 8).unwrap_or(0))
            };
            entries.push(Entry {
                tag,
                typ,
                size,
                count,
                data,
            });
        }
        Ok((entries, self.u32(end).map_or(0, u64::from)))
    }

    /// An entry's values as numbers (RATIONALs as quotients), at most `max` of them;
    /// `None` where they run past the end.
    fn values(&self, e: &Entry, max: u64) -> Option<Vec<f64>> {
        (0..e.count.min(max))
            .map(|k| {
                let o = e.data + k * e.size;
                let byte = || self.bytes::<1>(o).map(|[v]| v);
                Some(match e.typ {
                    1 | 2 | 7 => f64::from(byte()?),
                    6 => f64::from(byte()? as i8),
                    3 => f64::from(self.u16(o)?),
                    8 => f64::from(self.u16(o)? as i16),
                    4 | 13 => f64::from(self.u32(o)?),
                    9 => f64::from(self.u32(o)? as i32),
                    5 => f64::from(self.u32(o)?) / f64::from(self.u32(o + 4)?.max(1)),
                    10 => {
                        f64::from(self.u32(o)? as i32) / f64::from((self.u32(o + 4)? as i32).max(1))
                    }
                    _ => f64::NAN,
                })
            })
            .collect()
    }
}

/// The first directory of a TIFF (where our DNGs and many others keep the raw image
/// and the EXIF settings). Bounds are checked: a truncated file is an error.
pub(super) fn tiff_ifd0(b: &[u8]) -> Result<Ifd, String> {
    let (t, first) = Tiff::open(b, 0).ok_or("not a TIFF")?;
    let (entries, _) = t.directory(first, 0)?;
    let mut out = Ifd::new();
    // IFD-typed tags (SubIFDs' offsets) are links, not values; FLOAT and DOUBLE are
    // kept as NaN, which no reader of these tags takes.
    for e in entries.iter().filter(|e| e.typ != 13) {
        if e.count > 1 << 24 {
            return Err(format!("tag {}: absurd count {}", e.tag, e.count));
        }
        let values = t
            .values(e, e.count)
            .filter(|_| e.data + e.size * e.count <= t.len())
            .ok_or_else(|| format!("truncated TIFF (tag {} points past the end)", e.tag))?;
        out.insert(e.tag, values);
    }
    Ok(out)
}

fn truncated(len: u64, what: &str, end: u64) -> String {
    format!("truncated at byte {len}: {what} runs to byte {end}")
}

/// The most directories [`where_cut`] reads: a camera writes a handful (a preview, the
/// raw image, a thumbnail, EXIF); past this a file's links are going in circles.
const MAX_DIRECTORIES: usize = 128;

/// Where a TIFF (DNG, CR2, NEF, ARW and their kin) whose header is at byte `base` was
/// cut, in words: the first directory, tag data, or strip or tile of an image reachable
/// from its header (the chain of directories, SubIFDs, EXIF, GPS) that runs past the
/// file's end; `missing` before the words where an image has fewer tiles than its size
/// needs (its data was never written). `None` where all of it is in the file.
pub(super) fn where_cut(b: &[u8], base: u64, missing: &str) -> Option<String> {
    let (t, first) = Tiff::open(b, base)?;
    let len = t.len();
    let mut queue = vec![first];
    let mut seen = std::collections::HashSet::new();
    while let Some(at) = queue.pop() {
        if at == base || !seen.insert(at) || seen.len() > MAX_DIRECTORIES {
            continue;
        }
        let (entries, next) = match t.directory(at, base) {
            Ok(found) => found,
            Err(why) => return Some(why),
        };
        let first_value = |tag: u16| {
            let e = entries.iter().find(|e| e.tag == tag)?;
            t.values(e, 1)?.first().map(|&v| v as u64)
        };
        let list = |tag: u16| {
            let e = entries.iter().find(|e| e.tag == tag)?;
            t.values(e, 1 << 20)
                .map(|v| v.into_iter().map(|v| v as u64).collect::<Vec<_>>())
        };
        for e in &entries {
            let end = e.data + e.size * e.count;
            if end > len {
                return Some(format!(
                    "truncated at byte {len}: tag {} points past the end (to byte {end})",
                    e.tag
                ));
            }
            if matches!(e.tag, 330 | 34665 | 34853) {
                let offsets = if e.typ == 7 {
                    vec![e.data]
                } else {
                    list(e.tag)
                        .unwrap_or_default()
                        .into_iter()
                        .map(|o| base + o)
                        .collect()
                };
                queue.extend(offsets);
            }
        }
        let dims = [256, 257, 322, 323].map(first_value);
        if let ([Some(w), Some(h), Some(tw), Some(th)], Some(offsets)) = (dims, list(324))
            && tw > 0
            && th > 0
        {
            let needed = w.div_ceil(tw).saturating_mul(h.div_ceil(th));
            if (offsets.len() as u64) < needed {
                return Some(format!(
                    "{missing}: {} of the {needed} tiles a {w} × {h} image needs are in the file",
                    offsets.len()
                ));
            }
        }
        for (offsets, counts) in [(273, 279), (324, 325)] {
            if let (Some(offsets), Some(counts)) = (list(offsets), list(counts)) {
                let end = offsets
                    .iter()
                    .zip(&counts)
                    .map(|(o, c)| base + o + c)
                    .max()
                    .unwrap_or(0);
                if end > len {
                    return Some(truncated(len, "the image data", end));
                }
            }
        }
        if next != 0 {
            queue.push(base + next);
        }
    }
    None
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

/// Whether the first directory holds a CFA image in JPEG tiles or strips coded with the
/// DCT (a baseline, extended or progressive frame: lossy) rather than lossless JPEG, the
/// one JPEG the DNG specification allows for a mosaic: what Blackmagic cameras record
/// as CinemaDNG at 3:1 and above. Read from the first tile's markers up to its frame.
pub(super) fn lossy_jpeg_mosaic(b: &[u8], ifd: &Ifd) -> bool {
    if first_tag(ifd, TAG_PHOTOMETRIC) != Some(32803.0)
        || first_tag(ifd, TAG_COMPRESSION) != Some(7.0)
    {
        return false;
    }
    let Some(mut at) = first_tag(ifd, TAG_TILE_OFFSETS)
        .or_else(|| first_tag(ifd, TAG_STRIP_OFFSETS))
        .filter(|o| o.is_finite() && *o >= 0.0)
        .map(|o| o as usize)
    else {
        return false;
    };
    if b.get(at..at + 2) != Some(&[0xFF, 0xD8]) {
        return false;
    }
    at += 2;
    // Each segment: FF, its marker, a big-endian length counting itself.
    while let Some(&[0xFF, marker, hi, lo]) = b.get(at..at + 4) {
        match marker {
            0xC0..=0xC2 | 0xC9 | 0xCA => return true,
            0xC3 | 0xDA | 0xD9 => return false,
            _ => at += 2 + usize::from(u16::from_be_bytes([hi, lo])),
        }
    }
    false
}
