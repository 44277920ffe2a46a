//! How a RAW file is damaged, where its own structure says so: a directory, a tag's
//! data, the image's strips or tiles, or a box that the file's length does not reach.
//! Read only when every decoder has refused a file, to tell a truncated copy (a card
//! pulled out mid-write, a download cut short) from a camera nobody reads.

/// The first sign of damage found, in words ("truncated at byte N: …"), or `None`
/// where the file's structure is whole as far as it can be followed.
#[must_use]
pub fn diagnose(b: &[u8]) -> Option<String> {
    if b.starts_with(b"FUJIFILMCCD-RAW") {
        return raf(b);
    }
    if b.get(4..8) == Some(b"ftyp") {
        return boxes(b);
    }
    tiff(b, 0)
}

/// How [`diagnose`] begins when the image data is not in the file at all (a copy with
/// only its metadata kept): no picture, rather than a damaged one.
pub const MISSING: &str = "its image data is missing";

fn truncated(len: usize, what: &str, end: u64) -> String {
    format!("truncated at byte {len}: {what} runs to byte {end}")
}

/// A TIFF (DNG, CR2, NEF, ARW, PEF, ORF, RW2 and their kin) starting at `base`: every
/// directory reachable from the header (the chain, SubIFDs, EXIF), each tag's data, and
/// each image's strips or tiles.
fn tiff(b: &[u8], base: usize) -> Option<String> {
    let le = match b.get(base..base + 2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let u16_at = |o: u64| -> Option<u16> {
        let o = usize::try_from(o).ok()?;
        let s = b.get(o..o.checked_add(2)?)?;
        Some(if le {
            u16::from_le_bytes([s[0], s[1]])
        } else {
            u16::from_be_bytes([s[0], s[1]])
        })
    };
    let u32_at = |o: u64| -> Option<u32> {
        let o = usize::try_from(o).ok()?;
        let s = b.get(o..o.checked_add(4)?)?;
        let a = [s[0], s[1], s[2], s[3]];
        Some(if le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    };
    let base = base as u64;
    let len = b.len();
    // TIFF 42, Panasonic's 0x55, Olympus's "RO" and "SR".
    if !matches!(u16_at(base + 2)?, 42 | 0x55 | 0x4F52 | 0x5352) {
        return None;
    }
    let mut queue = vec![u64::from(u32_at(base + 4)?)];
    let mut seen = std::collections::HashSet::new();
    while let Some(rel) = queue.pop() {
        // A malicious file can link directories in a loop, or into thousands.
        if rel == 0 || !seen.insert(rel) || seen.len() > 64 {
            continue;
        }
        let at = base + rel;
        let Some(n) = u16_at(at) else {
            return Some(format!(
                "truncated at byte {len}: a directory starts at byte {at}"
            ));
        };
        let entries_end = at + 2 + 12 * u64::from(n);
        if entries_end > len as u64 {
            return Some(truncated(len, "a directory", entries_end));
        }
        let mut image: [Option<Vec<u64>>; 2] = [None, None];
        // Width, length, tile width, tile length: how many tiles the image needs.
        let mut dims: [Option<u64>; 4] = [None; 4];
        let mut counts: [Option<Vec<u64>>; 2] = [None, None];
        for e in 0..u64::from(n) {
            let entry = at + 2 + 12 * e;
            let (tag, typ, count) = (u16_at(entry)?, u16_at(entry + 2)?, u32_at(entry + 4)?);
            let size: u64 = match typ {
                1 | 2 | 6 | 7 => 1,
                3 | 8 => 2,
                4 | 9 | 11 | 13 => 4,
                5 | 10 | 12 => 8,
                _ => continue,
            };
            let bytes = size * u64::from(count);
            let data = if bytes <= 4 {
                entry + 8
            } else {
                base + u64::from(u32_at(entry + 8)?)
            };
            if data + bytes > len as u64 {
                return Some(format!(
                    "truncated at byte {len}: tag {tag} points past the end (to byte {})",
                    data + bytes
                ));
            }
            let values = || -> Option<Vec<u64>> {
                (0..u64::from(count).min(1 << 20))
                    .map(|k| match size {
                        2 => u16_at(data + 2 * k).map(u64::from),
                        4 => u32_at(data + 4 * k).map(u64::from),
                        _ => None,
                    })
                    .collect()
            };
            match tag {
                // SubIFDs and the EXIF directory.
                330 | 34665 => queue.extend(values().unwrap_or_default()),
                273 => image[0] = values(),
                279 => counts[0] = values(),
                324 => image[1] = values(),
                325 => counts[1] = values(),
                256 => dims[0] = values().and_then(|v| v.first().copied()),
                257 => dims[1] = values().and_then(|v| v.first().copied()),
                322 => dims[2] = values().and_then(|v| v.first().copied()),
                323 => dims[3] = values().and_then(|v| v.first().copied()),
                _ => {}
            }
        }
        if let ([Some(w), Some(h), Some(tw), Some(th)], Some(offsets)) = (dims, &image[1])
            && tw > 0
            && th > 0
        {
            let needed = w.div_ceil(tw) * h.div_ceil(th);
            if (offsets.len() as u64) < needed {
                return Some(format!(
                    "{MISSING}: {} of the {needed} tiles a {w} × {h} image \
                     needs are in the file",
                    offsets.len()
                ));
            }
        }
        for (offsets, counts) in image.iter().zip(&counts) {
            if let (Some(offsets), Some(counts)) = (offsets, counts) {
                let end = offsets
                    .iter()
                    .zip(counts)
                    .map(|(o, c)| base + o + c)
                    .max()
                    .unwrap_or(0);
                if end > len as u64 {
                    return Some(truncated(len, "the image data", end));
                }
            }
        }
        if let Some(next) = u32_at(entries_end) {
            queue.push(u64::from(next));
        }
    }
    None
}

/// Fujifilm's RAF: a header of big-endian offsets to an embedded JPEG and the CFA
/// data (a TIFF in later bodies).
fn raf(b: &[u8]) -> Option<String> {
    let be = |o: usize| -> Option<u64> {
        b.get(o..o + 4)
            .map(|s| u64::from(u32::from_be_bytes([s[0], s[1], s[2], s[3]])))
    };
    let len = b.len();
    for (what, offset, length) in [
        ("the preview", 84, 88),
        ("the CFA header", 92, 96),
        ("the CFA data", 100, 104),
    ] {
        let end = be(offset)? + be(length)?;
        if end > len as u64 {
            return Some(truncated(len, what, end));
        }
    }
    None
}

/// ISO base media files (Canon's CR3): each top-level box must fit in the file.
fn boxes(b: &[u8]) -> Option<String> {
    let len = b.len() as u64;
    let mut at = 0u64;
    while at + 8 <= len {
        let i = usize::try_from(at).ok()?;
        let size = u64::from(u32::from_be_bytes(b[i..i + 4].try_into().ok()?));
        let kind = String::from_utf8_lossy(&b[i + 4..i + 8]).into_owned();
        let size = match size {
            0 => len - at,
            1 => u64::from_be_bytes(b.get(i + 8..i + 16)?.try_into().ok()?),
            s => s,
        };
        if size < 8 {
            return Some(format!(
                "a box at byte {at} declares a size of {size} bytes"
            ));
        }
        if at + size > len {
            return Some(truncated(
                len as usize,
                &format!("the '{kind}' box"),
                at + size,
            ));
        }
        at += size;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_whole_tiff_is_not_damaged_and_a_cut_one_says_where() {
        // A little-endian TIFF: one directory with one strip of 16 bytes at 38.
        let mut t = b"II*\0\x08\0\0\0".to_vec();
        t.extend_from_slice(&2u16.to_le_bytes());
        for (tag, value) in [(273u16, 38u32), (279, 16)] {
            t.extend_from_slice(&tag.to_le_bytes());
            t.extend_from_slice(&4u16.to_le_bytes());
            t.extend_from_slice(&1u32.to_le_bytes());
            t.extend_from_slice(&value.to_le_bytes());
        }
        t.extend_from_slice(&0u32.to_le_bytes());
        t.extend_from_slice(&[7; 16]);
        assert_eq!(t.len(), 54);
        assert_eq!(diagnose(&t), None);
        assert_eq!(
            diagnose(&t[..40]).as_deref(),
            Some("truncated at byte 40: the image data runs to byte 54")
        );
        assert_eq!(
            diagnose(&t[..12]).as_deref(),
            Some("truncated at byte 12: a directory runs to byte 34")
        );
    }

    #[test]
    fn a_cut_box_is_named() {
        let mut f = 20u32.to_be_bytes().to_vec();
        f.extend_from_slice(b"ftypcrx ");
        f.extend_from_slice(&[0; 8]);
        f.extend_from_slice(&100u32.to_be_bytes());
        f.extend_from_slice(b"moov");
        assert_eq!(
            diagnose(&f).as_deref(),
            Some("truncated at byte 28: the 'moov' box runs to byte 120")
        );
    }
}
