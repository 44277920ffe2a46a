//! How a RAW file is damaged, where its own structure says so: a directory, a tag's
//! data, the image's strips or tiles, or a box that the file's length does not reach.
//! Read when every decoder has refused a file, to tell a truncated copy (a card pulled
//! out mid-write, a download cut short) from a camera nobody reads; and, for the damage
//! a decoder cannot survive, before any decoder is handed the file.

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
    tiff_walk(b, 0, Look::All)
}

/// The damage no decoder may be handed, in words, or `None`. rawler sizes what it
/// allocates by what the file declares before it reads it: a box's size, a table's
/// entry count, a tag's value count, the link to a TIFF's next directory. A box smaller
/// than its own header or a loop of directories makes it read the same bytes forever,
/// and a count beyond the file's bytes asks for more memory than a machine has: either
/// ends the process (an allocation failure aborts; no panic to catch). Such a file is
/// refused here first.
#[must_use]
pub fn before_decoding(b: &[u8]) -> Option<String> {
    if b.get(4..8) == Some(b"ftyp") {
        return boxes(b);
    }
    let be32 = |o: usize| {
        b.get(o..o + 4)
            .map(|s| u32::from_be_bytes([s[0], s[1], s[2], s[3]]))
    };
    if b.starts_with(b"FUJIFILMCCD-RAW") {
        // Two TIFFs: the preview JPEG's EXIF, and the one holding the CFA's directory.
        let exif = be32(84).map_or(0, |o| o as usize + 12);
        let cfa = be32(100).map_or(0, |o| o as usize);
        return tiff_walk(b, exif, Look::Hazards).or_else(|| tiff_walk(b, cfa, Look::Hazards));
    }
    if b.starts_with(b"\0MRM") {
        let at = match mrw_tiff(b) {
            Ok(at) => at,
            Err(why) => return Some(why),
        };
        // rawler reads its directory at byte 8 of the block, big-endian, whatever the
        // block's own header says.
        return walk_dirs(
            b,
            Dir {
                at: at + 8,
                data_base: at,
                little_endian: false,
                chained: false,
                look: Look::Hazards,
            },
        );
    }
    tiff_walk(b, 0, Look::Hazards)
}

/// Where a Minolta MRW's TIFF block (TTW) begins, among the blocks before its image
/// data, as rawler finds it: at the file's start where there is none.
fn mrw_tiff(b: &[u8]) -> Result<u64, String> {
    let be32 = |o: usize| {
        b.get(o..o + 4)
            .map_or(0, |s| u32::from_be_bytes([s[0], s[1], s[2], s[3]]))
    };
    let data_offset = be32(4) as usize + 8;
    let mut at = 8usize;
    let mut tiff = 0;
    while at + 20 < data_offset {
        let (tag, len) = (be32(at), be32(at + 4));
        if tag == 0x0054_5457 {
            tiff = at as u64 + 8;
        }
        // PRD: the sensor's size, for which rawler reserves an image before lensblur
        // can check it.
        let be16 = |o: usize| {
            b.get(o..o + 2)
                .map_or(0, |s| u64::from(u16::from_be_bytes([s[0], s[1]])))
        };
        if tag == 0x0050_5244
            && be16(at + 16) * be16(at + 18) > crate::limits::MAX_IMAGE_PIXELS as u64
        {
            return Err(format!(
                "its PRD block declares a {} × {} image, more than {} pixels",
                be16(at + 18),
                be16(at + 16),
                crate::limits::MAX_IMAGE_PIXELS
            ));
        }
        // rawler adds a block's length and header in 32 bits.
        match len.wrapping_add(8) {
            0 => {
                return Err(format!(
                    "the block at byte {at} declares a length that wraps to 0"
                ));
            }
            step => at += step as usize,
        }
    }
    Ok(tiff)
}

/// What [`diagnose`] begins with when the image data is not in the file at all (a copy
/// with only its metadata kept): no picture, rather than a damaged one.
pub const MISSING: &str = "its image data is missing";

fn truncated(len: usize, what: &str, end: u64) -> String {
    format!("truncated at byte {len}: {what} runs to byte {end}")
}

/// The most directories rawler is let follow in a TIFF's chain: a camera writes a
/// handful (a preview, the raw image, a thumbnail), and each costs rawler up to
/// thousands of entries.
const MAX_CHAIN: usize = 64;

/// The most samples an image may declare: the largest image lensblur reads, in four
/// samples a pixel (RGBA, the most a camera's TIFF holds).
const MAX_SAMPLES: u64 = 4 * crate::limits::MAX_IMAGE_PIXELS as u64;

/// Which damage [`tiff_walk`] reports.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Look {
    /// Only what a decoder cannot survive (see [`before_decoding`]).
    Hazards,
    /// Everything: the hazards, and data or directories past the end.
    All,
}

/// A directory for [`tiff_walk`] to read.
#[derive(Clone, Copy)]
struct Dir {
    /// Where it is in the file.
    at: u64,
    /// What its offsets count from (a maker note's embedded TIFF has its own start).
    data_base: u64,
    little_endian: bool,
    /// In the chain from the header, which rawler follows to its end however long, with
    /// each one's sub-directories.
    chained: bool,
    look: Look,
}

/// A TIFF (DNG, CR2, NEF, ARW, PEF, ORF, RW2 and their kin) starting at `base`: every
/// directory reachable from the header (the chain, SubIFDs, EXIF, GPS), each tag's
/// data, and each image's strips or tiles; for the hazards, the directories rawler
/// also reads (the maker note, the ICC profile it takes for one). The hazards first,
/// wherever they are: a chain of directories that links back into itself, and a tag
/// declaring more values than the whole file holds.
fn tiff_walk(b: &[u8], base: usize, look: Look) -> Option<String> {
    let little_endian = match b.get(base..base + 2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let base = base as u64;
    // TIFF 42, Panasonic's 0x55, Olympus's "RO" and "SR".
    if !matches!(
        u16_at(b, base + 2, little_endian)?,
        42 | 0x55 | 0x4F52 | 0x5352
    ) {
        return None;
    }
    let first = u64::from(u32_at(b, base + 4, little_endian)?);
    walk_dirs(
        b,
        Dir {
            at: base + first,
            data_base: base,
            little_endian,
            chained: first != 0,
            look,
        },
    )
}

fn u16_at(b: &[u8], o: u64, le: bool) -> Option<u16> {
    let o = usize::try_from(o).ok()?;
    let s = b.get(o..o.checked_add(2)?)?;
    Some(if le {
        u16::from_le_bytes([s[0], s[1]])
    } else {
        u16::from_be_bytes([s[0], s[1]])
    })
}

fn u32_at(b: &[u8], o: u64, le: bool) -> Option<u32> {
    let o = usize::try_from(o).ok()?;
    let s = b.get(o..o.checked_add(4)?)?;
    let a = [s[0], s[1], s[2], s[3]];
    Some(if le {
        u32::from_le_bytes(a)
    } else {
        u32::from_be_bytes(a)
    })
}

/// The directories reachable from `root`, as [`tiff_walk`] reads them.
fn walk_dirs(b: &[u8], root: Dir) -> Option<String> {
    let u16_at = |o: u64, le: bool| u16_at(b, o, le);
    let u32_at = |o: u64, le: bool| u32_at(b, o, le);
    let len = b.len();
    let mut queue = vec![root];
    let mut seen = std::collections::HashSet::new();
    let mut chain = std::collections::HashSet::new();
    while let Some(dir) = queue.pop() {
        let Dir {
            at,
            data_base,
            little_endian: le,
            chained,
            look,
        } = dir;
        if chained {
            if !chain.insert(at) {
                return Some(format!(
                    "the chain of directories links back to the one at byte {at}"
                ));
            }
            if chain.len() > MAX_CHAIN {
                return Some(format!(
                    "the chain of directories runs past {MAX_CHAIN} (a camera writes a few)"
                ));
            }
        }
        // A malicious file can link directories into thousands.
        if at == data_base || !seen.insert(at) || seen.len() > 2 * MAX_CHAIN {
            continue;
        }
        let all = look == Look::All;
        let Some(n) = u16_at(at, le) else {
            if !all {
                continue;
            }
            return Some(format!(
                "truncated at byte {len}: a directory starts at byte {at}"
            ));
        };
        let entries_end = at + 2 + 12 * u64::from(n);
        if all && entries_end > len as u64 {
            return Some(truncated(len, "a directory", entries_end));
        }
        // rawler reads the entries of a cut directory that the file holds (up to 4096).
        let n = u64::from(n)
            .min((len as u64).saturating_sub(at + 2) / 12)
            .min(4096);
        let mut image: [Option<Vec<u64>>; 2] = [None, None];
        // Width, length, tile width, tile length: how many tiles the image needs.
        let mut dims: [Option<u64>; 4] = [None; 4];
        let mut samples_per_pixel = 1;
        let mut compression = None;
        let mut counts: [Option<Vec<u64>>; 2] = [None, None];
        for e in 0..n {
            let entry = at + 2 + 12 * e;
            let (tag, typ, count) = (
                u16_at(entry, le)?,
                u16_at(entry + 2, le)?,
                u32_at(entry + 4, le)?,
            );
            let size: u64 = match typ {
                1 | 2 | 6 | 7 => 1,
                3 | 8 => 2,
                4 | 9 | 11 | 13 => 4,
                5 | 10 | 12 => 8,
                // rawler reads a type it does not know as bytes.
                _ if !all => 1,
                _ => continue,
            };
            let bytes = size * u64::from(count);
            if bytes > len as u64 {
                return Some(format!(
                    "tag {tag} declares {count} values of {size} bytes, more than the file's \
                     {len} bytes hold"
                ));
            }
            let data = if bytes <= 4 {
                entry + 8
            } else {
                data_base + u64::from(u32_at(entry + 8, le)?)
            };
            if all && data + bytes > len as u64 {
                return Some(format!(
                    "truncated at byte {len}: tag {tag} points past the end (to byte {})",
                    data + bytes
                ));
            }
            let values = || -> Option<Vec<u64>> {
                (0..u64::from(count).min(1 << 20))
                    .map(|k| match size {
                        2 => u16_at(data + 2 * k, le).map(u64::from),
                        4 => u32_at(data + 4 * k, le).map(u64::from),
                        _ => None,
                    })
                    .collect()
            };
            let sub = |at: u64, look: Look| Dir {
                at,
                data_base,
                little_endian: le,
                chained: false,
                look,
            };
            match tag {
                // SubIFDs, the EXIF and GPS directories, CR2's Kodak one, RAF's Fuji one,
                // where rawler
                // looks for them: at the offsets a LONG tag lists, or at the data of an
                // UNDEFINED one. It reads an ICC profile's bytes as a directory so too,
                // and allocates by whatever counts they make: that one is checked for
                // the hazards alone. Only the chain's own are read as rawler reads them.
                330 | 34665 | 34853 | 33424 | 61440 | 34675 if chained || all => {
                    let offsets = if typ == 7 {
                        vec![data]
                    } else {
                        let v = values().unwrap_or_default();
                        v.into_iter().map(|o| data_base + o).collect()
                    };
                    let look = if matches!(tag, 33424 | 34675) {
                        Look::Hazards
                    } else {
                        look
                    };
                    queue.extend(offsets.into_iter().map(|o| sub(o, look)));
                }
                37500 if typ == 7 => queue.extend(maker_note(b, data, data_base, le)),
                273 => image[0] = values(),
                279 => counts[0] = values(),
                324 => image[1] = values(),
                325 => counts[1] = values(),
                259 => compression = values().and_then(|v| v.first().copied()),
                256 => dims[0] = values().and_then(|v| v.first().copied()),
                257 => dims[1] = values().and_then(|v| v.first().copied()),
                322 => dims[2] = values().and_then(|v| v.first().copied()),
                323 => dims[3] = values().and_then(|v| v.first().copied()),
                277 => samples_per_pixel = values().and_then(|v| v.first().copied()).unwrap_or(1),
                _ => {}
            }
        }
        // rawler sizes the image it decodes by width × length × samples per pixel,
        // without the bounds lensblur checks the header's size against.
        if let [Some(w), Some(h), ..] = dims
            && w.saturating_mul(h).saturating_mul(samples_per_pixel) > MAX_SAMPLES
        {
            return Some(format!(
                "a directory declares a {w} × {h} image of {samples_per_pixel} samples a \
                 pixel, more than {MAX_SAMPLES} samples"
            ));
        }
        // Lossless JPEG strips or tiles: rawler sizes each one's image by its own frame
        // header, not by the directory.
        if compression == Some(7) {
            for (offsets, counts) in image.iter().zip(&counts) {
                if let (Some(offsets), Some(counts)) = (offsets, counts)
                    && let Some(why) = offsets
                        .iter()
                        .zip(counts)
                        .find_map(|(&o, &c)| ljpeg_frame(b, data_base + o, c))
                {
                    return Some(why);
                }
            }
        }
        if all
            && let ([Some(w), Some(h), Some(tw), Some(th)], Some(offsets)) = (dims, &image[1])
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
        for (offsets, counts) in image.iter().zip(&counts).filter(|_| all) {
            if let (Some(offsets), Some(counts)) = (offsets, counts) {
                let end = offsets
                    .iter()
                    .zip(counts)
                    .map(|(o, c)| data_base + o + c)
                    .max()
                    .unwrap_or(0);
                if end > len as u64 {
                    return Some(truncated(len, "the image data", end));
                }
            }
        }
        // rawler follows only the chain; what follows another directory matters only
        // to where the file was cut.
        if let Some(next) = u32_at(entries_end, le).filter(|&n| n != 0 && (chained || all)) {
            queue.push(Dir {
                at: data_base + u64::from(next),
                ..dir
            });
        }
    }
    None
}

/// A lossless JPEG (at byte `at`, `count` bytes) whose frame header (SOF3) declares
/// more samples than any image lensblur reads.
fn ljpeg_frame(b: &[u8], at: u64, count: u64) -> Option<String> {
    let start = usize::try_from(at).ok()?;
    let end = usize::try_from(at.saturating_add(count)).ok()?.min(b.len());
    let jpeg = b.get(start..end)?;
    let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC3])?;
    let f = jpeg.get(sof + 5..sof + 10)?;
    let (h, w, components) = (
        u64::from(u16::from_be_bytes([f[0], f[1]])),
        u64::from(u16::from_be_bytes([f[2], f[3]])),
        u64::from(f[4]),
    );
    (w * h * components > MAX_SAMPLES).then(|| {
        format!(
            "the lossless JPEG at byte {at} declares a {w} × {h} frame of {components} \
             components, more than {MAX_SAMPLES} samples"
        )
    })
}

/// The directory a maker note (tag 37500, its data at byte `data`) holds, where rawler
/// reads it: after the maker's name where one comes first (Olympus, Epson, Fujifilm,
/// Sony, Pentax), in an embedded TIFF of its own (Nikon), in the byte order it names.
/// Checked for the hazards alone: a maker note's layout is the maker's.
fn maker_note(b: &[u8], data: u64, data_base: u64, le: bool) -> Option<Dir> {
    let d = b.get(usize::try_from(data).ok()?..)?;
    let starts = |p: &[u8]| d.starts_with(p);
    let order = |o: usize| match d.get(o..o + 2) {
        Some(b"II") => Some(true),
        Some(b"MM") => Some(false),
        _ => None,
    };
    let dir = |at: u64, data_base: u64, little_endian: bool| Dir {
        at,
        data_base,
        little_endian,
        chained: false,
        look: Look::Hazards,
    };
    if starts(b"PENTAX") {
        return Some(dir(data + 10, data, order(8) == Some(true)));
    }
    if starts(b"Nikon\0\x02") {
        return Some(dir(data + 18, data + 10, order(10) == Some(true)));
    }
    let mut off = 0;
    if starts(b"OLYMP") {
        off += if starts(b"OLYMPUS") { 12 } else { 8 };
    }
    if starts(b"EPSON") {
        off += 8;
    }
    if starts(b"FUJIFILM") || starts(b"SONY DSC ") {
        off += 12;
    }
    if starts(b"AOC\0") {
        off += 4;
    }
    let le = match order(off) {
        Some(le) => {
            off += 2;
            le
        }
        None => le,
    };
    Some(dir(data + off as u64, data_base, le))
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

/// The CR3 box (a uuid) in which Canon keeps its metadata: the CMT TIFFs, CCTP, the
/// thumbnail.
const CR3_DESC: [u8; 16] = [
    0x85, 0xc0, 0xb6, 0x87, 0x82, 0x0f, 0x11, 0xe0, 0x81, 0x11, 0xf4, 0xce, 0x46, 0x2b, 0x6a, 0x48,
];

/// What a CR3 reader makes of a box's content, by the box it is in: boxes of its own
/// (after the fixed fields some begin with), a table sized by a count, a TIFF.
enum Content {
    /// Skipped by its size.
    Opaque,
    /// Boxes, from this many bytes into the content.
    Boxes(u64),
    /// A count (a big-endian u32 this many bytes in) of entries of this many bytes,
    /// following the count.
    Table(u64, u64),
    /// stsz: a sample size, then a count of samples whose sizes follow only where that
    /// size is 0.
    SampleSizes,
    /// A TIFF filling the content (CMT1 to CMT4).
    Tiff,
    /// The box's header alone: what follows it is read as more of its parent's boxes
    /// (rawler reads a moov's uuid boxes other than Canon's so).
    Transparent,
}

/// How rawler, the CR3 reader, walks a box of type `kind` inside `parent` (`None`: the
/// file's top level): mirrored so that every count it allocates by is checked here.
fn content(parent: Option<&[u8; 4]>, kind: &[u8; 4], uuid: Option<&[u8]>) -> Content {
    let canon = uuid == Some(&CR3_DESC[..]);
    match (parent.map(|p| &p[..]), &kind[..]) {
        (None, b"moov")
        | (Some(b"moov"), b"trak")
        | (Some(b"trak"), b"mdia")
        | (Some(b"mdia"), b"minf")
        | (Some(b"minf"), b"stbl") => Content::Boxes(0),
        (Some(b"moov"), b"uuid") if canon => Content::Boxes(0),
        (Some(b"moov"), b"uuid") => Content::Transparent,
        // Version and flags, then an entry count rawler does not use.
        (Some(b"stbl"), b"stsd") => Content::Boxes(8),
        (Some(b"stbl"), b"stts" | b"co64") => Content::Table(4, 8),
        (Some(b"stbl"), b"stsc") => Content::Table(4, 12),
        (Some(b"stbl"), b"stsz") => Content::SampleSizes,
        // The image description's 82 bytes of fields.
        (Some(b"stsd"), b"CRAW") => Content::Boxes(82),
        (Some(b"stsd"), b"CTMD") => Content::Table(8, 8),
        (Some(b"CRAW"), b"CDI1") => Content::Boxes(4),
        (Some(b"uuid"), b"CCTP") => Content::Boxes(12),
        (Some(b"uuid"), b"CMT1" | b"CMT2" | b"CMT3" | b"CMT4") => Content::Tiff,
        _ => Content::Opaque,
    }
}

/// ISO base media files (Canon's CR3): every box rawler descends into fits in its
/// parent (each top-level box in the file) and is no smaller than its own header, every
/// table's entries fit in their box, and the TIFFs in Canon's CMT boxes are whole enough
/// to read (see [`before_decoding`]).
fn boxes(b: &[u8]) -> Option<String> {
    walk(b, 0, b.len() as u64, None).err().or_else(|| ctmd(b))
}

/// The boxes directly inside `start..end`, each as its type, where its content starts
/// and where it ends; read once [`walk`] found them whole.
fn children(b: &[u8], start: u64, end: u64) -> Vec<([u8; 4], u64, u64)> {
    let mut v = Vec::new();
    let mut at = start;
    while at + 8 <= end {
        let Some(i) = usize::try_from(at).ok() else {
            break;
        };
        let kind = [b[i + 4], b[i + 5], b[i + 6], b[i + 7]];
        let mut header = 8;
        let size = match u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]) {
            0 => end - at,
            1 => {
                header = 16;
                b.get(i + 8..i + 16).map_or(0, |s| {
                    u64::from_be_bytes([s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]])
                })
            }
            s => u64::from(s),
        };
        if &kind == b"uuid" {
            header += 16;
        }
        if size < header || at + size > end {
            break;
        }
        v.push((kind, at + header, at + size));
        at += size;
    }
    v
}

/// The records of a CR3's CTMD sample (in the mdat, where its track's tables place
/// it), as rawler reads them: each record's size, which rawler reserves before it looks
/// whether the sample holds it, within the sample; and the TIFFs of its EXIF and maker
/// note blocks whole enough to read.
fn ctmd(b: &[u8]) -> Option<String> {
    let be32 = |o: u64| {
        let o = usize::try_from(o).ok()?;
        b.get(o..o + 4)
            .map(|s| u64::from(u32::from_be_bytes([s[0], s[1], s[2], s[3]])))
    };
    let first = |start: u64, end: u64, kind: &[u8; 4]| {
        children(b, start, end)
            .into_iter()
            .find(|c| &c.0 == kind)
            .map(|c| (c.1, c.2))
    };
    let moov = first(0, b.len() as u64, b"moov")?;
    for trak in children(b, moov.0, moov.1)
        .into_iter()
        .filter(|c| &c.0 == b"trak")
    {
        let Some(stbl) = first(trak.1, trak.2, b"mdia")
            .and_then(|m| first(m.0, m.1, b"minf"))
            .and_then(|m| first(m.0, m.1, b"stbl"))
        else {
            continue;
        };
        let Some(stsd) = first(stbl.0, stbl.1, b"stsd") else {
            continue;
        };
        if stsd.0 + 8 > stsd.1 || first(stsd.0 + 8, stsd.1, b"CTMD").is_none() {
            continue;
        }
        // The first sample: in the first chunk the sample-to-chunk table names, at that
        // chunk's offset, of the one size the sizes table gives or its first.
        let (stsc, stsz, co64) = (
            first(stbl.0, stbl.1, b"stsc")?,
            first(stbl.0, stbl.1, b"stsz")?,
            first(stbl.0, stbl.1, b"co64")?,
        );
        let chunk = be32(stsc.0 + 8)?.checked_sub(1)?;
        let o = usize::try_from(co64.0 + 8 + 8 * chunk).ok()?;
        let offset = u64::from_be_bytes(b.get(o..o + 8)?.try_into().ok()?);
        let size = match be32(stsz.0 + 4)? {
            0 => be32(stsz.0 + 12)?,
            s => s,
        };
        let sample =
            b.get(usize::try_from(offset).ok()?..usize::try_from(offset.checked_add(size)?).ok()?)?;
        let mut at = 0usize;
        while sample.len() - at >= 12 {
            let le32 = |o: usize| {
                u32::from_le_bytes([sample[o], sample[o + 1], sample[o + 2], sample[o + 3]])
            };
            let (rec_size, rec_type) = (
                le32(at) as usize,
                u16::from_le_bytes([sample[at + 4], sample[at + 5]]),
            );
            let Some(payload) = rec_size
                .checked_sub(12)
                .filter(|n| *n <= sample.len() - at - 12)
            else {
                return Some(format!(
                    "a CTMD record at byte {} declares a size of {rec_size} bytes, where its \
                     12-byte header and the {} bytes left of its sample are",
                    offset + at as u64,
                    sample.len() - at
                ));
            };
            let data = &sample[at + 12..at + 12 + payload];
            at += 12 + payload;
            if !(7..=12).contains(&rec_type) {
                continue;
            }
            let mut p = 0;
            while data.len() - p >= 8 {
                let sz =
                    u32::from_le_bytes([data[p], data[p + 1], data[p + 2], data[p + 3]]) as usize;
                let tag = u16::from_le_bytes([data[p + 4], data[p + 5]]);
                let Some(n) = sz.checked_sub(8).filter(|n| *n <= data.len() - p - 8) else {
                    break;
                };
                let block = &data[p + 8..p + 8 + n];
                p += sz;
                if matches!(tag, 0x8769 | 0x927c)
                    && let Some(why) = tiff_walk(block, 0, Look::Hazards)
                {
                    return Some(format!(
                        "in a CTMD block at byte {}: {why}",
                        offset + (at - payload + p - sz) as u64
                    ));
                }
            }
        }
    }
    None
}

/// The boxes from byte `at` to `end`: the file's top level (`parent` `None`), or a
/// box's content.
fn walk(b: &[u8], mut at: u64, end: u64, parent: Option<&[u8; 4]>) -> Result<(), String> {
    let len = b.len() as u64;
    let name = |k: &[u8]| String::from_utf8_lossy(k).into_owned();
    let byte = |o: u64| usize::try_from(o).ok();
    let be32 = |o: u64| -> Option<u64> {
        let o = byte(o)?;
        Some(u64::from(u32::from_be_bytes(
            b.get(o..o + 4)?.try_into().ok()?,
        )))
    };
    let parent_name = parent.map(|p| name(p));
    while at < end {
        if at + 8 > end {
            return match &parent_name {
                // A few bytes after the last box: nothing reads them.
                None => Ok(()),
                Some(p) => Err(format!(
                    "the '{p}' box ends in {} bytes that are not a box",
                    end - at
                )),
            };
        }
        let i = byte(at).ok_or("a box lies past the addressable bytes")?;
        let kind: [u8; 4] = [b[i + 4], b[i + 5], b[i + 6], b[i + 7]];
        let mut header = 8;
        let size = match be32(at).unwrap_or(0) {
            // Up to the end of the file, at the top level only.
            0 if parent.is_none() => end - at,
            1 => {
                header = 16;
                let s = b.get(i + 8..i + 16).filter(|_| at + 16 <= end);
                s.map_or(0, |s| {
                    u64::from_be_bytes([s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]])
                })
            }
            s => s,
        };
        if &kind == b"uuid" {
            header += 16;
        }
        let kind_name = name(&kind);
        if size < header {
            return Err(format!(
                "the '{kind_name}' box at byte {at} declares a size of {size} bytes, \
                 less than its {header}-byte header"
            ));
        }
        let box_end = at.saturating_add(size);
        if box_end > end {
            return Err(match &parent_name {
                None => truncated(len as usize, &format!("the '{kind_name}' box"), box_end),
                Some(p) => format!(
                    "the '{kind_name}' box at byte {at} runs to byte {box_end}, \
                     past the end of its '{p}' box (byte {end})"
                ),
            });
        }
        let here = at;
        let start = at + header;
        let uuid = (&kind == b"uuid").then(|| &b[i + header as usize - 16..i + header as usize]);
        let inner = box_end - start;
        let count_past = |count_at: u64, entry: u64| -> Result<(), String> {
            let count = be32(start + count_at).filter(|_| count_at + 4 <= inner);
            let Some(count) = count else {
                return Err(format!(
                    "the '{kind_name}' box at byte {here} is too short ({inner} bytes) for its count"
                ));
            };
            if count_at + 4 + count * entry > inner {
                return Err(format!(
                    "the '{kind_name}' box at byte {here} lists {count} entries of {entry} bytes \
                     in {inner} bytes"
                ));
            }
            Ok(())
        };
        at = box_end;
        match content(parent, &kind, uuid) {
            Content::Opaque => {}
            Content::Transparent => at = start,
            Content::Boxes(skip) => {
                if skip < inner {
                    walk(b, start + skip, box_end, Some(&kind))?;
                }
            }
            Content::Table(count_at, entry) => count_past(count_at, entry)?,
            Content::SampleSizes => {
                count_past(8, 0)?;
                if be32(start + 4) == Some(0) {
                    count_past(8, 4)?;
                } else if let Some(count) = be32(start + 8)
                    // One size for every sample, and no table: rawler still reserves a
                    // size for each. Every sample takes a byte of the file at least.
                    && count > len
                {
                    return Err(format!(
                        "the '{kind_name}' box at byte {here} counts {count} samples, \
                         more than the file's {len} bytes"
                    ));
                }
            }
            Content::Tiff => {
                let tiff = &b[byte(start).unwrap_or(0)..byte(box_end).unwrap_or(0)];
                if let Some(why) = tiff_walk(tiff, 0, Look::Hazards) {
                    return Err(format!("in the '{kind_name}' box at byte {here}: {why}"));
                }
            }
        }
    }
    Ok(())
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

    /// A box: its size, its type, its content.
    fn bx(kind: &[u8; 4], content: &[u8]) -> Vec<u8> {
        let mut v = (8 + content.len() as u32).to_be_bytes().to_vec();
        v.extend_from_slice(kind);
        v.extend_from_slice(content);
        v
    }

    /// A table box's content: version and flags, then (after `fixed`) a count.
    fn table(fixed: &[u8], count: u32, entries: &[u8]) -> Vec<u8> {
        [&[0; 4][..], fixed, &count.to_be_bytes(), entries].concat()
    }

    /// A CR3's skeleton: ftyp, then moov / trak / mdia / minf / stbl holding `stbl`,
    /// then an mdat.
    fn cr3(stbl: &[u8]) -> Vec<u8> {
        let nest = [b"stbl", b"minf", b"mdia", b"trak", b"moov"]
            .into_iter()
            .fold(stbl.to_vec(), |inner, kind| bx(kind, &inner));
        [
            bx(b"ftyp", b"crx \0\0\0\x01crx "),
            nest,
            bx(b"mdat", &[0; 16]),
        ]
        .concat()
    }

    #[test]
    fn a_whole_box_tree_is_not_damaged() {
        let stbl = [
            bx(b"stsz", &table(&[0, 0, 0, 0], 2, &[0, 0, 0, 8, 0, 0, 0, 8])),
            bx(b"co64", &table(&[], 1, &[0; 8])),
            bx(b"stts", &table(&[], 1, &[0, 0, 0, 1, 0, 0, 0, 1])),
        ]
        .concat();
        assert_eq!(before_decoding(&cr3(&stbl)), None);
        assert_eq!(diagnose(&cr3(&stbl)), None);
    }

    #[test]
    fn a_box_claiming_more_than_its_parent_holds_is_refused_by_name() {
        // The trak says 1000 bytes; its moov holds far fewer.
        let mut f = cr3(&bx(b"free", &[0; 4]));
        let trak = f.windows(4).position(|w| w == b"trak").unwrap() - 4;
        f[trak..trak + 4].copy_from_slice(&1000u32.to_be_bytes());
        let why = before_decoding(&f).unwrap();
        assert!(
            why.starts_with(
                "the 'trak' box at byte 28 runs to byte 1028, past the end of its 'moov' box"
            ),
            "{why}"
        );
        // A box of 0 bytes inside another: rawler would read it forever.
        let f = cr3(&[0, 0, 0, 0, b'f', b'r', b'e', b'e']);
        let why = before_decoding(&f).unwrap();
        assert!(
            why.contains("'free' box at byte 60 declares a size of 0 bytes"),
            "{why}"
        );
        // Bytes at the end of a box that are no box.
        let f = cr3(&[0, 0, 0]);
        assert!(
            before_decoding(&f)
                .unwrap()
                .contains("'stbl' box ends in 3 bytes")
        );
    }

    #[test]
    fn a_table_counting_more_entries_than_its_box_holds_is_refused_by_name() {
        // 4 294 967 295 sample sizes (16 GiB to allocate) in a 20-byte box.
        let f = cr3(&bx(b"stsz", &table(&[0, 0, 0, 0], u32::MAX, &[0; 4])));
        let why = before_decoding(&f).unwrap();
        assert!(
            why.contains("'stsz' box at byte 60 lists 4294967295 entries of 4 bytes in 16 bytes"),
            "{why}"
        );
        let f = cr3(&bx(b"co64", &table(&[], 0x7fff_ffff, &[0; 8])));
        assert!(before_decoding(&f).unwrap().contains("'co64' box"));
        // One size for every sample: the count is still checked, against the file.
        let f = cr3(&bx(b"stsz", &table(&[0, 0, 0, 8], u32::MAX, &[])));
        assert!(
            before_decoding(&f)
                .unwrap()
                .contains("counts 4294967295 samples")
        );
    }

    #[test]
    fn a_tiff_whose_chain_loops_or_whose_count_exceeds_the_file_is_refused() {
        // One directory, one tag, whose next directory is itself.
        let mut t = b"II*\0\x08\0\0\0".to_vec();
        t.extend_from_slice(&1u16.to_le_bytes());
        t.extend_from_slice(&[0x0F, 0x01, 2, 0, 4, 0, 0, 0, b'A', b'B', b'C', 0]);
        t.extend_from_slice(&8u32.to_le_bytes());
        assert_eq!(
            before_decoding(&t).as_deref(),
            Some("the chain of directories links back to the one at byte 8")
        );
        // The same tag declaring 2^31 LONGs.
        t[22..26].copy_from_slice(&0u32.to_le_bytes());
        t[12..14].copy_from_slice(&4u16.to_le_bytes());
        t[14..18].copy_from_slice(&0x8000_0000u32.to_le_bytes());
        assert_eq!(
            before_decoding(&t).as_deref(),
            Some(
                "tag 271 declares 2147483648 values of 4 bytes, more than the file's 26 bytes hold"
            )
        );
    }

    #[test]
    fn an_image_declared_larger_than_any_read_is_refused_before_decoding() {
        // An MRW whose PRD block declares 65535 × 65535 pixels.
        let mut mrw = b"\0MRM".to_vec();
        mrw.extend_from_slice(&32u32.to_be_bytes());
        mrw.extend_from_slice(b"\0PRD");
        mrw.extend_from_slice(&24u32.to_be_bytes());
        mrw.extend_from_slice(&[0; 8]);
        mrw.extend_from_slice(&[0xFF; 4]);
        mrw.extend_from_slice(&[0; 12]);
        assert!(
            before_decoding(&mrw)
                .unwrap()
                .starts_with("its PRD block declares a 65535 × 65535 image"),
        );
        // A TIFF's lossless JPEG strip whose frame header says 65535 × 65535 × 2.
        let mut t = b"II*\0\x08\0\0\0".to_vec();
        t.extend_from_slice(&3u16.to_le_bytes());
        for (tag, typ, value) in [(259u16, 3u16, 7u32), (273, 4, 50), (279, 4, 12)] {
            t.extend_from_slice(&tag.to_le_bytes());
            t.extend_from_slice(&typ.to_le_bytes());
            t.extend_from_slice(&1u32.to_le_bytes());
            t.extend_from_slice(&value.to_le_bytes());
        }
        t.extend_from_slice(&0u32.to_le_bytes());
        t.extend_from_slice(&[0xFF, 0xD8, 0xFF, 0xC3, 0, 11, 16, 0xFF, 0xFF, 0xFF, 0xFF, 2]);
        assert_eq!(
            before_decoding(&t).as_deref(),
            Some(
                "the lossless JPEG at byte 50 declares a 65535 × 65535 frame of 2 components, \
                 more than 1200000000 samples"
            )
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
