//! How a RAW file is damaged, where its own structure says so: a directory, a tag's
//! data, the image's strips or tiles, or a box that the file's length does not reach.
//! Read when every decoder has refused a file, to tell a truncated copy (a card pulled
//! out mid-write, a download cut short) from a camera nobody reads. What a decoder
//! cannot survive is not looked for here: the worker process it runs in contains it
//! (`worker`).

use super::tiff::where_cut;

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
    where_cut(b, 0, MISSING)
}

/// What [`diagnose`] begins with when the image data is not in the file at all (a copy
/// with only its metadata kept): no picture, rather than a damaged one.
pub const MISSING: &str = "its image data is missing";

fn truncated(len: usize, what: &str, end: u64) -> String {
    format!("truncated at byte {len}: {what} runs to byte {end}")
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

/// ISO base media files (Canon's CR3): the first top-level box that runs past the
/// file's end (the mdat of a copy cut short, most often).
fn boxes(b: &[u8]) -> Option<String> {
    let len = b.len() as u64;
    let mut at = 0u64;
    while at + 8 <= len {
        let i = usize::try_from(at).ok()?;
        // The box's type as printable letters: a damaged one may hold any byte.
        let kind: String = b[i + 4..i + 8]
            .iter()
            .map(|&c| {
                if c.is_ascii_graphic() {
                    char::from(c)
                } else {
                    '?'
                }
            })
            .collect();
        let size = match u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]) {
            // To the end of the file.
            0 => return None,
            1 => u64::from_be_bytes(b.get(i + 8..i + 16)?.try_into().ok()?),
            s => u64::from(s),
        };
        if size < 8 {
            return None;
        }
        let end = at.saturating_add(size);
        if end > len {
            return Some(truncated(b.len(), &format!("the '{kind}' box"), end));
        }
        at = end;
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
        // A chain of directories that links back into itself is followed once.
        let mut looped = t.clone();
        looped[34..38].copy_from_slice(&8u32.to_le_bytes());
        assert_eq!(diagnose(&looped), None);
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
        // Whole, it is not damaged.
        f.resize(120, 0);
        assert_eq!(diagnose(&f), None);
    }
}
