//! The bytes a RAW decoding worker and its parent exchange (see [`super::worker`]): one
//! request (what to do, the file's name, and its bytes or only its length where the
//! worker reads the file itself; the memory the worker may take) and one answer (a
//! capture, a header, or a refusal) at a time, over the worker's standard input and
//! output. A mosaic goes over as its 16-bit samples, half the size of the planes the
//! parent makes of them; through a shared memory file where the parent gave the worker
//! one, else on the pipe. Both ends are the same build of this program, so numbers are
//! in the machine's own byte order and samples go over as they lie in memory.
//! What the parent reads is still checked against [`crate::limits`] before it is
//! allocated: a worker that stopped halfway through an answer must not make the parent
//! allocate by a count it never finished writing.

use super::LoadError;
use super::cfa::{Decoded, MosaicLayout};
use super::decoders::{DecodedMeta, Decoder, RawHeader};
use crate::limits;
use crate::plane::{CameraIdentity, Capture, Channel, ChannelPlane, Plane, RawMeta};
use std::fs::File;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

/// What the worker is asked to do with a RAW file's bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Job {
    /// The decoder chain of [`super::load_capture`].
    Load,
    /// The header-only passes of [`super::read_header`].
    Header,
    /// One decoder alone, as [`super::decode_raw_with`].
    With(Decoder),
}

/// What the worker answers, as the in-process decode would have returned it (as the
/// parent reads it, a mosaic's planes are made).
#[derive(Debug)]
pub(super) enum Answer {
    Load(Decoded, Decoder, DecodedMeta),
    Header(RawHeader),
    With(Decoded),
}

/// The request: job, memory limit (bytes of address space), the file's name, and
/// what the worker decodes.
pub(super) struct Request<'a> {
    pub job: Job,
    pub memory_bytes: u64,
    pub path: &'a Path,
    pub input: Input<'a>,
}

/// What the worker decodes.
#[derive(Clone, Copy)]
pub(super) enum Input<'a> {
    /// These bytes (the parent holds no file of them, or not as it is on disk).
    Bytes(&'a [u8]),
    /// The file at the request's path (absolute), which had this length when the
    /// parent read it.
    File { len: u64 },
}

const REQUEST: &[u8; 4] = b"LBrq";
const ANSWER: &[u8; 4] = b"LBan";
/// Longest string either end reads (a path, a camera's name, a refusal).
const MAX_STRING: u64 = 1 << 20;

fn decoder_code(d: Decoder) -> u8 {
    match d {
        Decoder::Rawler => 0,
        Decoder::Rawloader => 1,
        Decoder::Lensblur => 2,
        Decoder::Image => 3,
    }
}

fn decoder_of(code: u8) -> io::Result<Decoder> {
    Ok(match code {
        0 => Decoder::Rawler,
        1 => Decoder::Rawloader,
        2 => Decoder::Lensblur,
        3 => Decoder::Image,
        _ => return Err(bad("decoder")),
    })
}

fn bad(what: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, format!("malformed {what}"))
}

/// A writer of the format's numbers, strings and options.
struct Out<W: Write>(W);

impl<W: Write> Out<W> {
    fn u8(&mut self, v: u8) -> io::Result<()> {
        self.0.write_all(&[v])
    }
    fn u16(&mut self, v: u16) -> io::Result<()> {
        self.0.write_all(&v.to_ne_bytes())
    }
    fn u64(&mut self, v: u64) -> io::Result<()> {
        self.0.write_all(&v.to_ne_bytes())
    }
    fn usize(&mut self, v: usize) -> io::Result<()> {
        self.u64(v as u64)
    }
    fn f64(&mut self, v: f64) -> io::Result<()> {
        self.0.write_all(&v.to_ne_bytes())
    }
    fn bytes(&mut self, v: &[u8]) -> io::Result<()> {
        self.usize(v.len())?;
        self.0.write_all(v)
    }
    fn str(&mut self, v: &str) -> io::Result<()> {
        self.bytes(v.as_bytes())
    }
    fn opt<T>(
        &mut self,
        v: Option<T>,
        put: impl FnOnce(&mut Self, T) -> io::Result<()>,
    ) -> io::Result<()> {
        match v {
            None => self.u8(0),
            Some(v) => {
                self.u8(1)?;
                put(self, v)
            }
        }
    }
    fn opt_f64(&mut self, v: Option<f64>) -> io::Result<()> {
        self.opt(v, Self::f64)
    }
    fn opt_str(&mut self, v: Option<&str>) -> io::Result<()> {
        self.opt(v, Self::str)
    }
    fn f64s(&mut self, v: &[f64]) -> io::Result<()> {
        v.iter().try_for_each(|&x| self.f64(x))
    }
}

/// A reader of what [`Out`] writes.
struct In<R: Read>(R);

impl<R: Read> In<R> {
    fn array<const N: usize>(&mut self) -> io::Result<[u8; N]> {
        let mut a = [0; N];
        self.0.read_exact(&mut a)?;
        Ok(a)
    }
    fn u8(&mut self) -> io::Result<u8> {
        Ok(self.array::<1>()?[0])
    }
    fn u16(&mut self) -> io::Result<u16> {
        Ok(u16::from_ne_bytes(self.array()?))
    }
    fn u64(&mut self) -> io::Result<u64> {
        Ok(u64::from_ne_bytes(self.array()?))
    }
    /// A count or size, at most `max`.
    fn usize(&mut self, max: u64) -> io::Result<usize> {
        let v = self.u64()?;
        if v > max {
            return Err(bad("count"));
        }
        usize::try_from(v).map_err(|_| bad("count"))
    }
    fn f64(&mut self) -> io::Result<f64> {
        Ok(f64::from_ne_bytes(self.array()?))
    }
    fn bytes(&mut self, max: u64) -> io::Result<Vec<u8>> {
        let n = self.usize(max)?;
        let mut v = vec![0; n];
        self.0.read_exact(&mut v)?;
        Ok(v)
    }
    fn string(&mut self) -> io::Result<String> {
        String::from_utf8(self.bytes(MAX_STRING)?).map_err(|_| bad("string"))
    }
    fn opt<T>(&mut self, get: impl FnOnce(&mut Self) -> io::Result<T>) -> io::Result<Option<T>> {
        match self.u8()? {
            0 => Ok(None),
            1 => get(self).map(Some),
            _ => Err(bad("option")),
        }
    }
    fn opt_f64(&mut self) -> io::Result<Option<f64>> {
        self.opt(Self::f64)
    }
    fn opt_string(&mut self) -> io::Result<Option<String>> {
        self.opt(Self::string)
    }
    fn f64s<const N: usize>(&mut self) -> io::Result<[f64; N]> {
        let mut a = [0.0; N];
        for v in &mut a {
            *v = self.f64()?;
        }
        Ok(a)
    }
}

pub(super) fn write_request<W: Write>(w: W, r: &Request<'_>) -> io::Result<()> {
    let mut o = Out(w);
    o.0.write_all(REQUEST)?;
    let (job, decoder) = match r.job {
        Job::Load => (0, 0),
        Job::Header => (1, 0),
        Job::With(d) => (2, decoder_code(d)),
    };
    o.u8(job)?;
    o.u8(decoder)?;
    o.u64(r.memory_bytes)?;
    o.bytes(&path_bytes(r.path))?;
    match r.input {
        Input::Bytes(bytes) => {
            o.u8(0)?;
            o.bytes(bytes)?;
        }
        Input::File { len } => {
            o.u8(1)?;
            o.u64(len)?;
        }
    }
    o.0.flush()
}

/// A path as bytes, exactly where the system allows (a name need not be UTF-8).
#[cfg(unix)]
fn path_bytes(path: &Path) -> Vec<u8> {
    std::os::unix::ffi::OsStrExt::as_bytes(path.as_os_str()).to_vec()
}

#[cfg(not(unix))]
fn path_bytes(path: &Path) -> Vec<u8> {
    path.to_string_lossy().into_owned().into_bytes()
}

#[cfg(unix)]
fn path_of(bytes: Vec<u8>) -> io::Result<PathBuf> {
    let name: std::ffi::OsString = std::os::unix::ffi::OsStringExt::from_vec(bytes);
    Ok(name.into())
}

#[cfg(not(unix))]
fn path_of(bytes: Vec<u8>) -> io::Result<PathBuf> {
    String::from_utf8(bytes)
        .map(PathBuf::from)
        .map_err(|_| bad("path"))
}

/// Whether the worker can be handed `path` to read itself: the name goes over exactly.
pub(super) fn path_goes_over(path: &Path) -> bool {
    cfg!(unix) || path.to_str().is_some()
}

/// A [`Request`] as the worker reads it.
pub(super) struct Received {
    pub job: Job,
    pub memory_bytes: u64,
    pub path: PathBuf,
    pub input: ReceivedInput,
}

/// [`Input`] as the worker reads it.
pub(super) enum ReceivedInput {
    Bytes(Vec<u8>),
    File { len: u64 },
}

/// A request as the worker reads it; `None` at the end of the input (the parent is
/// done with this worker).
pub(super) fn read_request<R: Read>(r: R) -> io::Result<Option<Received>> {
    let mut i = In(r);
    let mut magic = [0; 4];
    match i.0.read(&mut magic[..1])? {
        0 => return Ok(None),
        _ => i.0.read_exact(&mut magic[1..])?,
    }
    if &magic != REQUEST {
        return Err(bad("request"));
    }
    let job = match (i.u8()?, i.u8()?) {
        (0, _) => Job::Load,
        (1, _) => Job::Header,
        (2, d) => Job::With(decoder_of(d)?),
        _ => return Err(bad("job")),
    };
    let memory_bytes = i.u64()?;
    let path = path_of(i.bytes(MAX_STRING)?)?;
    let input = match i.u8()? {
        0 => ReceivedInput::Bytes(i.bytes(limits::MAX_IMAGE_FILE_BYTES)?),
        1 => ReceivedInput::File { len: i.u64()? },
        _ => return Err(bad("input")),
    };
    Ok(Some(Received {
        job,
        memory_bytes,
        path,
        input,
    }))
}

/// Writes an answer; a mosaic's samples into `shared` where there is one.
pub(super) fn write_answer<W: Write>(
    w: W,
    answer: &Result<Answer, LoadError>,
    shared: Option<&File>,
) -> io::Result<()> {
    let mut o = Out(w);
    o.0.write_all(ANSWER)?;
    match answer {
        Err(e) => {
            o.u8(0)?;
            let (kind, reason) = error_parts(e);
            o.u8(kind)?;
            o.str(reason)?;
        }
        Ok(Answer::Load(decoded, decoder, meta)) => {
            o.u8(1)?;
            put_decoded(&mut o, decoded, shared)?;
            o.u8(decoder_code(*decoder))?;
            o.opt_f64(meta.focal_mm)?;
            o.opt_f64(meta.f_number)?;
            o.opt_str(meta.lens_model.as_deref())?;
            o.opt_f64(meta.subject_distance_m)?;
        }
        Ok(Answer::Header(((w, h), make, model))) => {
            o.u8(2)?;
            o.usize(*w)?;
            o.usize(*h)?;
            o.opt_str(make.as_deref())?;
            o.opt_str(model.as_deref())?;
        }
        Ok(Answer::With(decoded)) => {
            o.u8(3)?;
            put_decoded(&mut o, decoded, shared)?;
        }
    }
    o.0.flush()
}

/// The answer as the parent reads it, a mosaic made planes (its samples read from
/// `shared` where the worker put them there); a refusal names `path`, the parent's own
/// name for the file.
pub(super) fn read_answer<R: Read>(
    r: R,
    path: &Path,
    shared: Option<&File>,
) -> io::Result<Result<Answer, LoadError>> {
    let mut i = In(r);
    if &i.array::<4>()? != ANSWER {
        return Err(bad("answer"));
    }
    Ok(Ok(match i.u8()? {
        0 => {
            let kind = i.u8()?;
            let reason = i.string()?;
            return Ok(Err(error_of(kind, path, reason)?));
        }
        1 => {
            let capture = get_decoded(&mut i, shared)?;
            let decoder = decoder_of(i.u8()?)?;
            let meta = DecodedMeta {
                focal_mm: i.opt_f64()?,
                f_number: i.opt_f64()?,
                lens_model: i.opt_string()?,
                subject_distance_m: i.opt_f64()?,
            };
            Answer::Load(capture, decoder, meta)
        }
        2 => {
            let side = limits::MAX_IMAGE_SIDE as u64;
            let size = (i.usize(side)?, i.usize(side)?);
            Answer::Header((size, i.opt_string()?, i.opt_string()?))
        }
        3 => Answer::With(get_decoded(&mut i, shared)?),
        _ => return Err(bad("answer")),
    }))
}

fn error_parts(e: &LoadError) -> (u8, &str) {
    match e {
        LoadError::Unreadable { reason, .. } => (0, reason),
        LoadError::Corrupt { reason, .. } => (1, reason),
        LoadError::Damaged { reason, .. } => (2, reason),
        LoadError::Unsupported { reason, .. } => (3, reason),
        LoadError::NoImage { reason, .. } => (4, reason),
        LoadError::TooLarge { reason, .. } => (5, reason),
        LoadError::DecoderStopped { reason, .. } => (6, reason),
    }
}

fn error_of(kind: u8, path: &Path, reason: String) -> io::Result<LoadError> {
    let path = path.to_path_buf();
    Ok(match kind {
        0 => LoadError::Unreadable { path, reason },
        1 => LoadError::Corrupt { path, reason },
        2 => LoadError::Damaged { path, reason },
        3 => LoadError::Unsupported { path, reason },
        4 => LoadError::NoImage { path, reason },
        5 => LoadError::TooLarge { path, reason },
        6 => LoadError::DecoderStopped { path, reason },
        _ => return Err(bad("refusal")),
    })
}

fn channel_code(c: Channel) -> u8 {
    match c {
        Channel::R => 0,
        Channel::G => 1,
        Channel::B => 2,
        Channel::Y => 3,
    }
}

fn channel_of(code: u8) -> io::Result<Channel> {
    Ok(match code {
        0 => Channel::R,
        1 => Channel::G,
        2 => Channel::B,
        3 => Channel::Y,
        _ => return Err(bad("channel")),
    })
}

fn put_capture<W: Write>(o: &mut Out<W>, c: &Capture) -> io::Result<()> {
    o.usize(c.width)?;
    o.usize(c.height)?;
    o.usize(c.planes.len())?;
    for p in &c.planes {
        o.u8(channel_code(p.channel))?;
        o.usize(p.step)?;
        o.usize(p.offset_x)?;
        o.usize(p.offset_y)?;
        o.usize(p.plane.width)?;
        o.usize(p.plane.height)?;
        o.usize(p.plane.data.len())?;
        o.0.write_all(bytemuck::cast_slice(&p.plane.data))?;
    }
    o.opt_f64(c.setting_focal_mm)?;
    o.opt_f64(c.setting_f_number)?;
    o.opt_f64(c.setting_focus_m)?;
    for (_, v) in identity_fields(&c.identity) {
        o.opt_str(v)?;
    }
    o.u8(u8::from(c.is_raw))?;
    o.opt(c.raw.as_ref(), put_raw_meta)
}

/// Every field of an identity, in one fixed order (both ends use it).
fn identity_fields(id: &CameraIdentity) -> [(&'static str, Option<&str>); 5] {
    [
        ("make", id.make.as_deref()),
        ("model", id.model.as_deref()),
        ("body_serial", id.body_serial.as_deref()),
        ("lens_model", id.lens_model.as_deref()),
        ("lens_serial", id.lens_serial.as_deref()),
    ]
}

fn get_capture<R: Read>(i: &mut In<R>) -> io::Result<Capture> {
    let side = limits::MAX_IMAGE_SIDE as u64;
    let (width, height) = (i.usize(side)?, i.usize(side)?);
    let planes = (0..i.usize(16)?)
        .map(|_| {
            let channel = channel_of(i.u8()?)?;
            let (step, offset_x, offset_y) = (i.usize(16)?, i.usize(16)?, i.usize(16)?);
            let (w, h) = (i.usize(side)?, i.usize(side)?);
            let n = i.usize(limits::MAX_IMAGE_PIXELS as u64)?;
            if n != w * h {
                return Err(bad("plane"));
            }
            let mut data = vec![0f32; n];
            i.0.read_exact(bytemuck::cast_slice_mut(&mut data))?;
            Ok(ChannelPlane {
                channel,
                plane: Plane {
                    width: w,
                    height: h,
                    data,
                },
                step,
                offset_x,
                offset_y,
            })
        })
        .collect::<io::Result<Vec<_>>>()?;
    let mut c = Capture::of_planes(width, height, planes, false);
    c.setting_focal_mm = i.opt_f64()?;
    c.setting_f_number = i.opt_f64()?;
    c.setting_focus_m = i.opt_f64()?;
    c.identity = CameraIdentity {
        make: i.opt_string()?,
        model: i.opt_string()?,
        body_serial: i.opt_string()?,
        lens_model: i.opt_string()?,
        lens_serial: i.opt_string()?,
    };
    c.is_raw = i.u8()? != 0;
    c.raw = i.opt(get_raw_meta)?;
    Ok(c)
}

/// A decoder's answer: its capture, then its mosaic where it has one.
fn put_decoded<W: Write>(o: &mut Out<W>, d: &Decoded, shared: Option<&File>) -> io::Result<()> {
    put_capture(o, &d.capture)?;
    o.opt(d.mosaic.as_ref(), |o, m| {
        let l = &m.layout;
        o.usize(l.width)?;
        o.usize(l.height)?;
        for (&c, &b) in l.channels.iter().zip(&l.black) {
            o.u8(channel_code(c))?;
            o.f64(f64::from(b))?;
        }
        o.f64(f64::from(l.white))?;
        let samples: &[u8] = bytemuck::cast_slice(&m.values);
        match shared {
            Some(file) => {
                o.u8(1)?;
                o.usize(m.values.len())?;
                put_shared(file, samples)
            }
            None => {
                o.u8(0)?;
                o.bytes(samples)
            }
        }
    })
}

/// What [`put_decoded`] wrote, its mosaic made planes in one pass over its samples.
fn get_decoded<R: Read>(i: &mut In<R>, shared: Option<&File>) -> io::Result<Decoded> {
    let mut capture = get_capture(i)?;
    let mosaic = i.opt(|i| {
        let side = limits::MAX_IMAGE_SIDE as u64;
        let (width, height) = (i.usize(side)?, i.usize(side)?);
        let (mut channels, mut black) = ([Channel::G; 4], [0f32; 4]);
        for (c, b) in channels.iter_mut().zip(&mut black) {
            *c = channel_of(i.u8()?)?;
            *b = i.f64()? as f32;
        }
        let layout = MosaicLayout {
            width,
            height,
            channels,
            black,
            white: i.f64()? as f32,
        };
        let in_shared = match i.u8()? {
            0 => false,
            1 => true,
            _ => return Err(bad("mosaic")),
        };
        let n = i.usize(limits::MAX_IMAGE_PIXELS as u64)?;
        if n != width * height {
            return Err(bad("mosaic"));
        }
        if in_shared {
            let file = shared.ok_or_else(|| bad("mosaic"))?;
            get_shared(file, n, |values| layout.planes(values))
        } else if i.usize(2 * limits::MAX_IMAGE_PIXELS as u64)? == 2 * n {
            let mut values = vec![0u16; n];
            i.0.read_exact(bytemuck::cast_slice_mut(&mut values))?;
            Ok(layout.planes(&values))
        } else {
            Err(bad("mosaic"))
        }
    })?;
    if let Some(planes) = mosaic {
        capture.planes = planes;
    }
    Ok(Decoded::planes(capture))
}

/// The samples into the shared file, from its start (it holds nothing else).
#[cfg(unix)]
fn put_shared(file: &File, samples: &[u8]) -> io::Result<()> {
    use std::os::unix::fs::FileExt;
    file.set_len(0)?;
    file.write_all_at(samples, 0)
}

#[cfg(not(unix))]
fn put_shared(_: &File, _: &[u8]) -> io::Result<()> {
    Err(io::Error::other("no shared memory file on this system"))
}

/// `n` samples from the shared file, mapped rather than copied, handed to `f`; the file
/// emptied after (its memory is the system's again while the worker waits).
fn get_shared<T>(file: &File, n: usize, f: impl FnOnce(&[u16]) -> T) -> io::Result<T> {
    let len = 2 * n;
    if file.metadata()?.len() < len as u64 {
        return Err(bad("mosaic"));
    }
    let made = if n == 0 {
        f(&[])
    } else {
        // SAFETY: the file is the parent's own memory file; the worker wrote it before
        // answering and touches it again only for the next request, which comes after
        // this mapping is gone; its length was checked just above.
        let map = unsafe { memmap2::MmapOptions::new().len(len).populate().map(file)? };
        let values: &[u16] = bytemuck::try_cast_slice(&map[..]).map_err(|_| bad("mosaic"))?;
        f(values)
    };
    file.set_len(0)?;
    Ok(made)
}

fn put_raw_meta<W: Write>(o: &mut Out<W>, m: &RawMeta) -> io::Result<()> {
    o.0.write_all(&m.cfa)?;
    m.black.iter().try_for_each(|&b| o.u16(b))?;
    o.u16(m.white)?;
    o.opt(m.color_matrix.as_ref(), |o, rows| {
        rows.iter().try_for_each(|r| o.f64s(r))
    })?;
    o.u16(m.calibration_illuminant)?;
    o.opt(m.as_shot_neutral.as_ref(), |o, v| o.f64s(v))?;
    o.u16(m.orientation)?;
    o.opt_f64(m.exposure_s)?;
    o.opt(m.iso, |o, v| o.u64(u64::from(v)))?;
    o.opt_str(m.date_time_original.as_deref())?;
    o.opt_str(m.lens_make.as_deref())?;
    o.opt_f64(m.focal_35mm)?;
    o.opt(m.lens_specification.as_ref(), |o, v| o.f64s(v))?;
    o.opt_str(m.description.as_deref())
}

fn get_raw_meta<R: Read>(i: &mut In<R>) -> io::Result<RawMeta> {
    Ok(RawMeta {
        cfa: i.array()?,
        black: [i.u16()?, i.u16()?, i.u16()?, i.u16()?],
        white: i.u16()?,
        color_matrix: i.opt(|i| Ok([i.f64s()?, i.f64s()?, i.f64s()?]))?,
        calibration_illuminant: i.u16()?,
        as_shot_neutral: i.opt(In::f64s)?,
        orientation: i.u16()?,
        exposure_s: i.opt_f64()?,
        iso: i.opt(|i| u32::try_from(i.u64()?).map_err(|_| bad("ISO")))?,
        date_time_original: i.opt_string()?,
        lens_make: i.opt_string()?,
        focal_35mm: i.opt_f64()?,
        lens_specification: i.opt(In::f64s)?,
        description: i.opt_string()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A capture with every field set goes over and comes back equal, bit for bit
    /// (an infinite focus distance and a NaN-free plane included).
    #[test]
    fn a_capture_and_a_refusal_come_back_as_they_went() {
        let plane = |channel, offset_x| ChannelPlane {
            channel,
            plane: Plane::from_fn(5, 3, |x, y| x as f32 * 0.25 - y as f32 / 7.0),
            step: 2,
            offset_x,
            offset_y: 1,
        };
        let mut c = Capture::of_planes(
            10,
            6,
            vec![plane(Channel::R, 0), plane(Channel::B, 1)],
            true,
        );
        c.setting_focal_mm = Some(35.0);
        c.setting_focus_m = Some(f64::INFINITY);
        c.identity.make = Some("Canon".into());
        c.identity.lens_serial = Some("123".into());
        let mut meta = RawMeta::rggb(512, 16383);
        meta.iso = Some(400);
        meta.description = Some("made here".into());
        c.raw = Some(meta);
        let decoded = DecodedMeta {
            focal_mm: Some(50.0),
            f_number: None,
            lens_model: Some("EF 50".into()),
            subject_distance_m: Some(f64::INFINITY),
        };
        let mut buf = Vec::new();
        write_answer(
            &mut buf,
            &Ok(Answer::Load(
                Decoded::planes(c.clone()),
                Decoder::Rawler,
                decoded.clone(),
            )),
            None,
        )
        .unwrap();
        let Ok(Answer::Load(back, d, m)) =
            read_answer(buf.as_slice(), Path::new("x"), None).unwrap()
        else {
            panic!("not a load answer");
        };
        let back = back.into_capture();
        assert_eq!(
            (back.width, back.height, &back.planes),
            (c.width, c.height, &c.planes)
        );
        assert_eq!(
            (back.setting_focal_mm, back.setting_focus_m),
            (c.setting_focal_mm, c.setting_focus_m)
        );
        assert_eq!(
            (back.identity, back.is_raw, back.raw),
            (c.identity, c.is_raw, c.raw)
        );
        assert_eq!((d, m), (Decoder::Rawler, decoded));

        let refusal = LoadError::Damaged {
            path: "in-worker".into(),
            reason: "truncated at byte 9".into(),
        };
        let mut buf = Vec::new();
        write_answer(&mut buf, &Err(refusal), None).unwrap();
        let e = read_answer(buf.as_slice(), Path::new("shot.cr2"), None)
            .unwrap()
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "shot.cr2: damaged file: truncated at byte 9; copy it again from the card or the camera"
        );
        // An answer cut short is an error of the exchange, not a refusal.
        assert!(read_answer(&buf[..buf.len() - 1], Path::new("x"), None).is_err());
    }
}
