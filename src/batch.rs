//! Deblurring many photos with a library of lens profiles, each photo's profile picked
//! from its EXIF (as lens-profile libraries in raw converters do).
//!
//! A batch is planned before any image is decoded: each photo's header gives its
//! sensor size, camera and lens, focal length and aperture ([`crate::raw::read_header`]),
//! which pick its profile ([`ProfileLibrary::pick`]) or a reason to skip it. Then the
//! photos to deblur run several at a time, as many as the cores and the memory allow
//! ([`peak_bytes`]), each written atomically, so a batch stopped halfway and run again
//! redoes only the photos without a complete output ([`output_complete`]).
//!
//! Which profile fits a photo (the rule, once):
//! 1. its sensor size is the photo's;
//! 2. every camera or lens field the profile records (make, model, lens) is recorded by
//!    the photo with the same value. A profile that records none of the three is left
//!    out of a library: it would fit every camera;
//! 3. a serial (body or lens) recorded by both must agree, as
//!    [`crate::profile::Profile::check_identity`] requires; one only the profile records
//!    does not exclude it (that check warns there);
//! 4. among those that fit, the best is the one whose calibrated settings cover the
//!    photo's focal length and aperture, then the one whose serials agree with the
//!    photo's (that very lens unit's profile over its siblings'), then the one recording
//!    more of make, model and lens (specific over generic);
//! 5. two profiles equally best is ambiguous: the photo is skipped naming both;
//! 6. a best profile that does not cover the photo's setting skips it, unless
//!    extrapolation is allowed.

use crate::deblur::output::{deblurred_note, write_deblurred, write_like_original};
use crate::deblur::{DeblurOptions, ProfileKernels, deblur_capture};
use crate::job::JobContext;
use crate::plane::{CameraIdentity, Capture, LensSetting};
use crate::profile::Profile;
use crate::raw::{Header, LoadOptions};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex};

/// Errors that stop a whole batch before it starts (a photo's own trouble is a skip or
/// a failure of that photo, never this).
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    #[error("{}: cannot read the folder: {source}", path.display())]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: no such photo or folder", path.display())]
    Missing { path: PathBuf },
    #[error(
        "{}: the output folder is also a folder of photos (outputs would be read as photos on the next run)",
        path.display()
    )]
    OutputIsInput { path: PathBuf },
    #[error("{}: no lens profile in this folder or its subfolders", path.display())]
    NoProfiles { path: PathBuf },
    #[error(
        "the profile records no camera or lens, so the library could not tell which photos it is for; save it as a file and deblur with --profile"
    )]
    Unnamed,
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    #[error(transparent)]
    Profile(#[from] crate::profile::ProfileError),
}

/// Where a profile went in a library: its file, and whether it replaced one of the
/// same camera and lens (kept beside it as `<file>.previous`, which no library reads).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SavedToLibrary {
    pub path: PathBuf,
    pub replaced: bool,
}

/// The file extensions a folder's photos are recognised by (a photo named on its own
/// is always taken): DNG, TIFF, PNG, JPEG and the camera RAW formats the RAW decoder
/// reads. Everything else in a folder (sidecars, JSON) is not a photo.
pub const PHOTO_EXTENSIONS: &[&str] = &[
    "dng", "tif", "tiff", "png", "jpg", "jpeg", "3fr", "ari", "arw", "cr2", "cr3", "crw", "dcr",
    "dcs", "erf", "iiq", "kdc", "mef", "mos", "mrw", "nef", "nrw", "orf", "pef", "raf", "raw",
    "rw2", "rwl", "sr2", "srf", "srw", "x3f",
];

/// The format a batch writes, by its extension.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OutputFormat {
    /// Each photo as its own kind: a RAW photo's CFA as a DNG (the RAW editor develops
    /// it as it did the original), an RGB photo in its own format and colour (a JPEG
    /// in, a JPEG out, its ICC profile and EXIF kept).
    #[default]
    Auto,
    /// 16-bit linear TIFF (camera RGB for a RAW photo: for pipelines that want it).
    Tiff,
    /// 16-bit linear PNG.
    Png,
    /// The deblurred CFA as a DNG.
    Dng,
}

impl OutputFormat {
    #[must_use]
    pub fn extension(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Tiff => "tiff",
            Self::Png => "png",
            Self::Dng => "dng",
        }
    }
}

/// The photos named: files as they are, folders as their photos (by
/// [`PHOTO_EXTENSIONS`], not recursively, hidden files left out: a writer's temporary
/// files are hidden), in name order, each once.
///
/// # Errors
/// A path that does not exist, a folder that cannot be listed, or a folder that is the
/// output folder.
pub fn collect_photos(inputs: &[PathBuf], out_dir: &Path) -> Result<Vec<PathBuf>, BatchError> {
    let out_canon = out_dir.canonicalize().ok();
    let mut photos = Vec::new();
    for input in inputs {
        if input.is_dir() {
            if out_canon.is_some() && input.canonicalize().ok() == out_canon {
                return Err(BatchError::OutputIsInput {
                    path: input.clone(),
                });
            }
            let entries = std::fs::read_dir(input).map_err(|source| BatchError::Folder {
                path: input.clone(),
                source,
            })?;
            let mut found: Vec<PathBuf> = entries
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file() && is_photo_name(p))
                .collect();
            found.sort();
            photos.extend(found);
        } else if input.exists() {
            photos.push(input.clone());
        } else {
            return Err(BatchError::Missing {
                path: input.clone(),
            });
        }
    }
    let mut seen = std::collections::HashSet::new();
    photos.retain(|p| seen.insert(p.canonicalize().unwrap_or_else(|_| p.clone())));
    Ok(photos)
}

fn is_photo_name(p: &Path) -> bool {
    let hidden = p
        .file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with('.'));
    let ext = p
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    !hidden && PHOTO_EXTENSIONS.contains(&ext.as_str())
}

/// One profile of a library and the file it came from.
#[derive(Clone, Debug)]
pub struct LibraryProfile {
    pub path: PathBuf,
    pub profile: Profile,
}

/// How many folders deep a profile library is searched: session folders inside a
/// folder per lens or per camera, and no further (a library is not a whole disk).
const LIBRARY_DEPTH: usize = 4;

/// The `*.json` files of `dir` and, `depth` folders down, of its subfolders; hidden
/// files and folders and the results caches left out. Only `dir` itself must be
/// listable: a subfolder that cannot be read is passed over.
fn json_files(dir: &Path, depth: usize, files: &mut Vec<PathBuf>) -> Result<(), BatchError> {
    let entries = std::fs::read_dir(dir).map_err(|source| BatchError::Folder {
        path: dir.to_path_buf(),
        source,
    })?;
    for path in entries.flatten().map(|e| e.path()) {
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        if name.starts_with('.') {
            continue;
        }
        if path.is_dir() {
            if depth > 0 && name != crate::pipeline::RESULTS_DIR {
                let _ = json_files(&path, depth - 1, files);
            }
        } else if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            files.push(path);
        }
    }
    Ok(())
}

/// The profiles a batch picks from.
#[derive(Clone, Debug, Default)]
pub struct ProfileLibrary {
    pub profiles: Vec<LibraryProfile>,
    /// One line per file left out: a damaged profile, one that names no camera or lens.
    pub warnings: Vec<String>,
}

impl ProfileLibrary {
    /// Every lensblur profile among the `*.json` files of a folder and its subfolders
    /// (a library of session folders, each with the `profile.json` the studio wrote,
    /// is one; results caches and hidden folders are passed over). Other lensblur
    /// files and other JSON are ignored; a file that claims to be a profile but does
    /// not load, or is not JSON at all, is one warning and left out.
    ///
    /// # Errors
    /// The folder cannot be listed, or holds no usable profile.
    pub fn load(dir: &Path) -> Result<Self, BatchError> {
        let mut files = Vec::new();
        json_files(dir, LIBRARY_DEPTH, &mut files)?;
        files.sort();
        let mut profiles = Vec::new();
        let mut warnings = Vec::new();
        for path in files {
            let text = match crate::io::read_json_text(&path) {
                Ok(t) => t,
                Err(e) => {
                    warnings.push(e.to_string());
                    continue;
                }
            };
            let schema = match serde_json::from_str::<serde_json::Value>(&text) {
                Ok(v) => v.get("schema").and_then(|s| s.as_str()).map(str::to_owned),
                Err(e) => {
                    warnings.push(format!("{}: not JSON, left out: {e}", path.display()));
                    continue;
                }
            };
            let tag = crate::profile::PROFILE.tag();
            let kind = tag.split('/').next().unwrap_or_default();
            if schema.is_none_or(|s| s.split('/').next() != Some(kind)) {
                continue;
            }
            match Profile::from_json(&text, &path.display().to_string()) {
                Ok(profile) => profiles.push(LibraryProfile { path, profile }),
                Err(e) => warnings.push(format!("{e}; left out")),
            }
        }
        let mut library = Self {
            profiles: Vec::new(),
            warnings,
        };
        for p in profiles {
            library.add(p);
        }
        if library.profiles.is_empty() {
            return Err(BatchError::NoProfiles {
                path: dir.to_path_buf(),
            });
        }
        Ok(library)
    }

    /// A library of the one profile a person chose (the studio's): it applies to any
    /// photo of its sensor size whose recorded identity does not contradict it, even
    /// when it records no camera or lens, since it was picked by hand, not by EXIF.
    #[must_use]
    pub fn chosen(path: PathBuf, profile: Profile) -> Self {
        Self {
            profiles: vec![LibraryProfile { path, profile }],
            warnings: Vec::new(),
        }
    }

    /// Saves `profile` into the library folder `dir` (made if missing) as
    /// `<camera, lens (serials)>.profile.json`: one file per camera and lens unit, so a
    /// new calibration of a lens replaces its last one, which is kept as `….previous`.
    ///
    /// # Errors
    /// The profile names no camera or lens (the library would leave it out), or the
    /// folder or file cannot be written.
    pub fn save_into(dir: &Path, profile: &Profile) -> Result<SavedToLibrary, BatchError> {
        let id = &profile.identity;
        if id.make.is_none() && id.model.is_none() && id.lens_model.is_none() {
            return Err(BatchError::Unnamed);
        }
        let name: String = id
            .describe()
            .chars()
            .map(|c| {
                if c.is_alphanumeric() || " -_.,()+".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        crate::io::create_dir_all(dir)?;
        let path = dir.join(format!("{}.profile.json", name.trim()));
        let replaced = path.is_file();
        if replaced {
            let previous = path.with_extension("json.previous");
            std::fs::rename(&path, &previous).map_err(|source| crate::io::WriteError {
                path: previous,
                source,
            })?;
        }
        profile.save(&path)?;
        Ok(SavedToLibrary { path, replaced })
    }

    /// Adds a profile, or a warning where it names no camera or lens (rule 2).
    pub fn add(&mut self, p: LibraryProfile) {
        let id = &p.profile.identity;
        if id.make.is_none() && id.model.is_none() && id.lens_model.is_none() {
            self.warnings.push(format!(
                "{}: records no camera or lens, so it would fit any photo; left out (use it with --profile)",
                p.path.display()
            ));
        } else {
            self.profiles.push(p);
        }
    }

    /// The profile for a photo by the module's rule, or why there is none.
    ///
    /// # Errors
    /// The [`Skip`] that says why.
    pub fn pick(&self, photo: &PhotoFacts, allow_extrapolation: bool) -> Result<Pick, Skip> {
        let (Some(focal_mm), Some(f_number)) = (photo.focal_mm, photo.f_number) else {
            return Err(Skip::NoSettings {
                missing: match (photo.focal_mm, photo.f_number) {
                    (None, None) => "focal length and aperture",
                    (None, _) => "focal length",
                    _ => "aperture",
                },
            });
        };
        let setting = LensSetting { focal_mm, f_number };
        let mut ranked: Vec<(Rank, usize)> = self
            .profiles
            .iter()
            .enumerate()
            .filter_map(|(i, p)| rank(&p.profile, photo, setting).map(|r| (r, i)))
            .collect();
        ranked.sort_by_key(|r| std::cmp::Reverse(r.0));
        let Some(&(best, index)) = ranked.first() else {
            return Err(Skip::NoProfile {
                photo: format!(
                    "{}, {} × {}",
                    photo.identity.describe(),
                    photo.width,
                    photo.height
                ),
            });
        };
        if let Some(&(_, other)) = ranked.get(1).filter(|(r, _)| *r == best) {
            return Err(Skip::Ambiguous {
                first: self.profiles[index].path.clone(),
                second: self.profiles[other].path.clone(),
            });
        }
        if !best.covers && !allow_extrapolation {
            let mut strict = self.profiles[index].profile.clone();
            strict.allow_extrapolation = false;
            let reason = strict.check_setting(setting).err().map_or_else(
                || "outside the calibrated settings".into(),
                |e| e.to_string(),
            );
            return Err(Skip::OutOfRange {
                profile: self.profiles[index].path.clone(),
                reason,
            });
        }
        Ok(Pick {
            index,
            setting,
            extrapolated: !best.covers,
        })
    }
}

/// How well a profile fits, compared field by field in this order (rule 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Rank {
    covers: bool,
    serials_agreeing: u8,
    type_fields: u8,
}

/// A profile's [`Rank`] for a photo, `None` where it does not fit (rules 1–3).
fn rank(profile: &Profile, photo: &PhotoFacts, setting: LensSetting) -> Option<Rank> {
    if (profile.norm.width, profile.norm.height) != (photo.width, photo.height) {
        return None;
    }
    let mut r = Rank {
        covers: false,
        serials_agreeing: 0,
        type_fields: 0,
    };
    let fields = profile
        .identity
        .fields()
        .into_iter()
        .zip(photo.identity.fields());
    for (k, ((_, mine), (_, theirs))) in fields.enumerate() {
        let serial = k >= 3;
        match (mine, theirs) {
            (Some(a), Some(b)) if !CameraIdentity::same_value(a, b) => return None,
            (Some(_), Some(_)) if serial => r.serials_agreeing += 1,
            (Some(_), Some(_)) => r.type_fields += 1,
            (Some(_), None) if !serial => return None,
            _ => {}
        }
    }
    r.covers = profile.covers(setting);
    Some(r)
}

/// What a batch needs to know of a photo before decoding it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PhotoFacts {
    pub width: usize,
    pub height: usize,
    pub focal_mm: Option<f64>,
    pub f_number: Option<f64>,
    pub identity: CameraIdentity,
}

impl From<&Header> for PhotoFacts {
    fn from(h: &Header) -> Self {
        Self {
            width: h.width,
            height: h.height,
            focal_mm: h.exif.focal_mm,
            f_number: h.exif.f_number,
            identity: h.exif.identity.clone(),
        }
    }
}

/// The profile chosen for a photo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pick {
    /// Into [`ProfileLibrary::profiles`].
    pub index: usize,
    pub setting: LensSetting,
    /// The setting is outside what the profile was calibrated on (allowed by the caller).
    pub extrapolated: bool,
}

/// Why a photo is not deblurred. Not a failure: a batch with skips succeeds.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Skip {
    #[error("cannot read it: {0}")]
    Unreadable(String),
    #[error("its EXIF has no {missing}")]
    NoSettings { missing: &'static str },
    #[error("no profile for {photo}")]
    NoProfile { photo: String },
    #[error("two profiles fit equally well: {} and {}", first.display(), second.display())]
    Ambiguous { first: PathBuf, second: PathBuf },
    #[error("{}: {reason}", profile.display())]
    OutOfRange { profile: PathBuf, reason: String },
    #[error("{} writes the same output", other.display())]
    SameOutput { other: PathBuf },
    #[error("the output would overwrite the photo")]
    OutputIsPhoto,
    #[error("its output is already complete")]
    Done,
    #[error("not a RAW photo: a DNG holds a RAW photo's CFA")]
    NotRaw,
}

impl Skip {
    /// The group a summary counts it under.
    #[must_use]
    pub fn group(&self) -> &'static str {
        match self {
            Self::Unreadable(_) => "unreadable",
            Self::NoSettings { .. } => "no focal length or aperture in EXIF",
            Self::NoProfile { .. } => "no matching profile",
            Self::Ambiguous { .. } => "ambiguous profile",
            Self::OutOfRange { .. } => "outside the calibrated range",
            Self::SameOutput { .. } | Self::OutputIsPhoto => "output name taken",
            Self::Done => "already done",
            Self::NotRaw => "not a RAW photo (DNG output)",
        }
    }
}

/// A batch's settings.
#[derive(Clone, Debug, Default)]
pub struct BatchOptions {
    pub out_dir: PathBuf,
    pub format: OutputFormat,
    pub allow_extrapolation: bool,
    pub deblur: DeblurOptions,
    /// Bytes the batch may take at once; `None` reads three quarters of the memory
    /// available now ([`memory_available`]).
    pub memory_budget: Option<u64>,
    /// Photos at once at most; `None`: one per core.
    pub max_parallel: Option<usize>,
    /// The kernels to deblur with; `None`: each profile's recommended (its shape model
    /// where it holds one). A photo whose profile lacks the model asked for fails.
    pub kernel_model: Option<crate::model::KernelModel>,
    /// Whether deblurring corrects the lens's lateral colour or leaves it for lensfun.
    pub lateral_colour: crate::model::LateralColour,
}

/// What the batch does with one photo.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Deblur { pick: Pick, pixels: usize },
    Skip(Skip),
}

/// One photo of a planned batch.
#[derive(Clone, Debug, PartialEq)]
pub struct Planned {
    pub photo: PathBuf,
    pub output: PathBuf,
    pub action: Action,
}

/// The output a photo gets: `<out_dir>/<stem>.<extension>`; with
/// [`OutputFormat::Auto`], `dng` for a RAW photo and the photo's own extension for
/// the others.
#[must_use]
pub fn output_path(photo: &Path, opts: &BatchOptions, is_raw: bool) -> PathBuf {
    let stem = photo
        .file_stem()
        .map_or_else(|| "photo".into(), |s| s.to_string_lossy().into_owned());
    let ext = match opts.format {
        OutputFormat::Auto if is_raw => "dng".to_string(),
        OutputFormat::Auto => photo.extension().map_or_else(
            || "tiff".into(),
            |e| e.to_string_lossy().to_ascii_lowercase(),
        ),
        f => f.extension().to_string(),
    };
    opts.out_dir.join(format!("{stem}.{ext}"))
}

/// Whether `output` is a finished output for a photo of `width × height`: its header
/// reads as an image of that size. Outputs are written whole or not at all
/// ([`crate::io::write_atomic`]), so a file that is there with the right header was
/// finished; a foreign or damaged file at that name is redone.
#[must_use]
pub fn output_complete(output: &Path, width: usize, height: usize) -> bool {
    crate::raw::read_header(output).is_ok_and(|h| (h.width, h.height) == (width, height))
}

/// Decides every photo's fate from its header alone (headers read in parallel).
#[must_use]
pub fn plan(photos: &[PathBuf], library: &ProfileLibrary, opts: &BatchOptions) -> Vec<Planned> {
    use rayon::prelude::*;
    let mut planned: Vec<Planned> = photos
        .par_iter()
        .map(|photo| {
            let header = crate::raw::read_header(photo);
            let output = output_path(photo, opts, header.as_ref().is_ok_and(|h| h.is_raw));
            let action = match header {
                Err(e) => Action::Skip(Skip::Unreadable(e.to_string())),
                Ok(h) if opts.format == OutputFormat::Dng && !h.is_raw => {
                    Action::Skip(Skip::NotRaw)
                }
                Ok(h) => {
                    let facts = PhotoFacts::from(&h);
                    match library.pick(&facts, opts.allow_extrapolation) {
                        Err(skip) => Action::Skip(skip),
                        Ok(_) if output_complete(&output, h.width, h.height) => {
                            Action::Skip(Skip::Done)
                        }
                        Ok(pick) => Action::Deblur {
                            pick,
                            pixels: h.width.saturating_mul(h.height),
                        },
                    }
                }
            };
            Planned {
                photo: photo.clone(),
                output,
                action,
            }
        })
        .collect();
    // Two photos of one name in different folders would overwrite each other: the first
    // keeps the name. A photo is never its own output.
    let mut taken: std::collections::HashMap<PathBuf, PathBuf> = Default::default();
    for p in &mut planned {
        let canon = |q: &Path| q.canonicalize().unwrap_or_else(|_| q.to_path_buf());
        if canon(&p.photo) == canon(&p.output) {
            p.action = Action::Skip(Skip::OutputIsPhoto);
        } else if let Some(other) = taken.get(&p.output) {
            p.action = Action::Skip(Skip::SameOutput {
                other: other.clone(),
            });
        } else {
            taken.insert(p.output.clone(), p.photo.clone());
        }
    }
    planned
}

/// What became of one photo.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Done {
        profile: PathBuf,
        setting: LensSetting,
        /// Where the photo was focused, metres, where its file says.
        focus_m: Option<f64>,
        extrapolated: bool,
        /// What the photo was (RAW, linear or developed), for the profile's
        /// [`crate::profile::Profile::picture_warning`].
        picture: crate::plane::PictureKind,
    },
    Skipped(Skip),
    /// Why, without the photo's name where the reason allows (the outcome names it).
    Failed(String),
    Cancelled,
}

#[derive(Clone, Debug, PartialEq)]
pub struct PhotoOutcome {
    pub photo: PathBuf,
    pub output: PathBuf,
    pub outcome: Outcome,
}

/// A finished (or cancelled) batch, photo by photo in the order given.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BatchReport {
    pub outcomes: Vec<PhotoOutcome>,
    /// Photos decoded, and photos written, at once at most (one deblurs at a time).
    pub parallel: usize,
}

impl BatchReport {
    #[must_use]
    pub fn count(&self, f: impl Fn(&Outcome) -> bool) -> usize {
        self.outcomes.iter().filter(|o| f(&o.outcome)).count()
    }

    #[must_use]
    pub fn failed(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Failed(_)))
    }

    /// The summary's lines: done, skipped by group, failed (and cancelled, if any).
    #[must_use]
    pub fn summary(&self) -> Vec<String> {
        let mut groups: Vec<(&'static str, usize)> = Vec::new();
        for o in &self.outcomes {
            if let Outcome::Skipped(s) = &o.outcome {
                match groups.iter_mut().find(|(g, _)| *g == s.group()) {
                    Some((_, n)) => *n += 1,
                    None => groups.push((s.group(), 1)),
                }
            }
        }
        let skipped: usize = groups.iter().map(|(_, n)| n).sum();
        let mut lines = vec![
            format!(
                "done: {}",
                self.count(|o| matches!(o, Outcome::Done { .. }))
            ),
            format!("skipped: {skipped}"),
        ];
        lines.extend(groups.iter().map(|(g, n)| format!("  {g}: {n}")));
        lines.push(format!("failed: {}", self.failed()));
        let cancelled = self.count(|o| matches!(o, Outcome::Cancelled));
        if cancelled > 0 {
            lines.push(format!("cancelled: {cancelled}"));
        }
        lines
    }
}

/// The step a batch leaves to its caller: write this deblurred photo (`photo`'s, with
/// the kernels `described` names) to `output` atomically. The command line adds its own
/// reporting; [`deblur_photos`] runs [`write_photo`].
pub type WriteOne<'a> = dyn Fn(&Path, &Capture, &Path, &str) -> Result<(), String> + Sync + 'a;

/// Writes a deblurred photo as a batch in `format` does: [`OutputFormat::Auto`] as its
/// original is ([`write_like_original`]), the others by `output`'s extension
/// ([`write_deblurred`]), with the note of what was done.
///
/// # Errors
/// The output cannot be written.
pub fn write_photo(
    photo: &Path,
    deblurred: &Capture,
    output: &Path,
    note: &str,
    format: OutputFormat,
) -> Result<crate::deblur::output::Written, crate::deblur::output::OutputError> {
    if format == OutputFormat::Auto {
        write_like_original(output, photo, deblurred, note)
    } else {
        let name = photo.file_name().map(|n| n.to_string_lossy().into_owned());
        write_deblurred(output, name, deblurred, note)
    }
}

/// Plans and runs a batch with the core's own writer ([`write_photo`], its errors as
/// text): what the studio's export of a set of photos runs.
#[must_use]
pub fn deblur_photos(
    photos: &[PathBuf],
    library: &ProfileLibrary,
    opts: &BatchOptions,
    job: &JobContext,
) -> BatchReport {
    let planned = plan(photos, library, opts);
    let method = opts.deblur.method;
    run(
        &planned,
        library,
        opts,
        job,
        &|photo, deblurred, out, described| {
            let note = deblurred_note(method, described);
            write_photo(photo, deblurred, out, &note, opts.format)
                .map(|_| ())
                .map_err(|e| e.to_string())
        },
    )
}

/// Peak memory of deblurring and writing one photo of `pixels` pixels: 48 bytes a
/// pixel (the worst measured, a 100 MP 16-bit TIFF: the file's bytes, the decoded
/// image, the linear f32 planes, the deblurred copy and the encoded output; a RAW
/// photo takes about 33) and 64 MiB of tile buffers.
#[must_use]
pub fn peak_bytes(pixels: usize) -> u64 {
    48 * pixels as u64 + (64 << 20)
}

/// `MemAvailable` of `/proc/meminfo`, in bytes; `None` where it cannot be read.
#[must_use]
pub fn memory_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_mem_available(&text)
}

fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

/// Memory reserved by photos in flight: a photo starts only when its [`peak_bytes`]
/// fits beside the others' within the budget, or when nothing else runs (one photo
/// larger than the budget still runs, alone).
struct Budget {
    limit: u64,
    used: Mutex<u64>,
    freed: Condvar,
}

impl Budget {
    fn take(&self, bytes: u64) {
        let mut used = self
            .used
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        while *used > 0 && used.saturating_add(bytes) > self.limit {
            used = self
                .freed
                .wait(used)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
        *used += bytes;
    }

    fn give(&self, bytes: u64) {
        let mut used = self
            .used
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *used = used.saturating_sub(bytes);
        self.freed.notify_all();
    }
}

/// A photo decoded, with its kernels, on its way to the deblur stage.
struct Loaded {
    index: usize,
    capture: Capture,
    source: ProfileKernels,
    described: String,
    done: Outcome,
}

/// A photo deblurred, on its way to be written.
struct Deblurred {
    index: usize,
    capture: Capture,
    described: String,
    done: Outcome,
}

/// What the stages share: the plan, the memory budget and the outcomes.
struct Stages<'a> {
    planned: &'a [Planned],
    library: &'a ProfileLibrary,
    opts: &'a BatchOptions,
    job: &'a JobContext,
    budget: Budget,
    results: Mutex<Vec<Option<Outcome>>>,
    finished: AtomicUsize,
    todo: usize,
}

impl Stages<'_> {
    /// Records a photo's outcome, frees its share of the budget, and reports progress.
    fn record(&self, index: usize, outcome: Outcome) {
        if let Action::Deblur { pixels, .. } = self.planned[index].action {
            self.budget.give(peak_bytes(pixels));
        }
        if let Ok(mut r) = self.results.lock() {
            r[index] = Some(outcome);
        }
        let n = self.finished.fetch_add(1, Ordering::Relaxed) + 1;
        self.job.report("deblur", n, self.todo);
    }

    /// The first stage: a photo decoded and checked against its header, its kernels
    /// made; or its outcome recorded (a failure, a cancel) and `None`.
    fn decode(&self, index: usize) -> Option<Loaded> {
        let p = &self.planned[index];
        let Action::Deblur { pick, pixels } = p.action else {
            return None;
        };
        if self.job.is_cancelled() {
            self.record(index, Outcome::Cancelled);
            return None;
        }
        self.budget.take(peak_bytes(pixels));
        match load_photo(p, pick, self.library, self.opts) {
            Ok((capture, source, described, profile)) => Some(Loaded {
                index,
                done: Outcome::Done {
                    profile,
                    setting: pick.setting,
                    focus_m: capture.setting_focus_m,
                    extrapolated: pick.extrapolated,
                    picture: capture.picture_kind(),
                },
                capture,
                source,
                described,
            }),
            Err(e) => {
                self.record(index, Outcome::Failed(e));
                None
            }
        }
    }

    /// The second stage, one photo at a time on every core (or the GPU).
    fn deblur(&self, l: Loaded) -> Option<Deblurred> {
        let quiet = self.job.without_progress();
        match deblur_capture(&l.capture, &l.source, &self.opts.deblur, &quiet) {
            Ok(capture) => Some(Deblurred {
                index: l.index,
                capture,
                described: l.described,
                done: l.done,
            }),
            Err(_) if self.job.is_cancelled() => {
                self.record(l.index, Outcome::Cancelled);
                None
            }
            Err(e) => {
                self.record(l.index, Outcome::Failed(e.to_string()));
                None
            }
        }
    }

    /// The third stage: the caller's writer.
    fn write(&self, d: Deblurred, write_one: &WriteOne<'_>) {
        let p = &self.planned[d.index];
        let outcome = match write_one(&p.photo, &d.capture, &p.output, &d.described) {
            Ok(()) => d.done,
            Err(e) => Outcome::Failed(e),
        };
        drop(d.capture);
        self.record(d.index, outcome);
    }
}

/// Photos decoded at once, and photos written at once: one each per four cores (at
/// least one, at most `max_parallel`), enough to keep the deblur fed where it is several
/// times faster than a decode or a write (on many cores, on a GPU) without photos decoded
/// far ahead waiting in memory; one each without a memory budget.
fn lanes(opts: &BatchOptions, budget: Option<u64>, todo: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    match budget {
        Some(_) => opts
            .max_parallel
            .unwrap_or(cores.div_ceil(4))
            .clamp(1, cores),
        None => 1,
    }
    .min(todo)
    .max(1)
}

/// Runs a planned batch as a three-stage pipeline, so that the decoding, deblurring and
/// writing of successive photos overlap and a batch runs at the speed of its slowest
/// stage, not their sum: [`lanes`] threads decode photos (each checked against its
/// header, with its profile's kernels), one deblurs them in turn on the calling thread
/// (every core of its rayon pool, or the GPU), and [`lanes`] threads hand them to
/// `write_one`. Stages pass photos through channels of one place, and a photo takes its
/// [`peak_bytes`] of the memory budget (see [`Budget`]; without one, one lane each) from
/// its decode to its write, so memory stays bounded whatever the batch's length.
/// "deblur" progress is reported per photo finished. A photo's failure is its outcome
/// and the batch goes on; after a cancel, photos not started are
/// [`Outcome::Cancelled`].
#[must_use]
pub fn run(
    planned: &[Planned],
    library: &ProfileLibrary,
    opts: &BatchOptions,
    job: &JobContext,
    write_one: &WriteOne<'_>,
) -> BatchReport {
    let todo: Vec<usize> = (0..planned.len())
        .filter(|&i| matches!(planned[i].action, Action::Deblur { .. }))
        .collect();
    let budget = opts
        .memory_budget
        .or_else(|| memory_available().map(|m| m / 4 * 3));
    let lanes = lanes(opts, budget, todo.len());
    let stages = Stages {
        planned,
        library,
        opts,
        job,
        budget: Budget {
            limit: budget.unwrap_or(u64::MAX),
            used: Mutex::new(0),
            freed: Condvar::new(),
        },
        results: Mutex::new(vec![None; planned.len()]),
        finished: AtomicUsize::new(0),
        todo: todo.len(),
    };
    job.report("deblur", 0, todo.len());
    let next = AtomicUsize::new(0);
    let (to_deblur, decoded) = std::sync::mpsc::sync_channel::<Loaded>(1);
    let (to_write, deblurred) = std::sync::mpsc::sync_channel::<Deblurred>(1);
    let deblurred = Mutex::new(deblurred);
    std::thread::scope(|s| {
        for _ in 0..lanes {
            let to_deblur = to_deblur.clone();
            let (stages, next, todo) = (&stages, &next, &todo);
            s.spawn(move || {
                while let Some(&i) = todo.get(next.fetch_add(1, Ordering::Relaxed)) {
                    if let Some(l) = stages.decode(i)
                        && to_deblur.send(l).is_err()
                    {
                        break;
                    }
                }
            });
        }
        drop(to_deblur);
        for _ in 0..lanes {
            let (stages, deblurred) = (&stages, &deblurred);
            s.spawn(move || {
                loop {
                    let d = match deblurred.lock() {
                        Ok(rx) => rx.recv(),
                        Err(_) => break,
                    };
                    let Ok(d) = d else { break };
                    stages.write(d, write_one);
                }
            });
        }
        // On this thread, so the deblur runs in the caller's rayon pool.
        for l in decoded {
            if let Some(d) = stages.deblur(l)
                && to_write.send(d).is_err()
            {
                break;
            }
        }
        drop(to_write);
    });
    let results = stages
        .results
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let outcomes = planned
        .iter()
        .zip(results)
        .map(|(p, r)| PhotoOutcome {
            photo: p.photo.clone(),
            output: p.output.clone(),
            outcome: match (&p.action, r) {
                (Action::Skip(s), _) => Outcome::Skipped(s.clone()),
                (Action::Deblur { .. }, Some(o)) => o,
                (Action::Deblur { .. }, None) => Outcome::Cancelled,
            },
        })
        .collect();
    BatchReport {
        outcomes,
        parallel: lanes,
    }
}

/// A photo decoded and checked against the size its header declared, with its
/// profile's kernels at its setting, how they are described, and the profile's file.
fn load_photo(
    p: &Planned,
    pick: Pick,
    library: &ProfileLibrary,
    opts: &BatchOptions,
) -> Result<(Capture, ProfileKernels, String, PathBuf), String> {
    let entry = library
        .profiles
        .get(pick.index)
        .ok_or_else(|| format!("no profile {} in the library", pick.index))?;
    let capture =
        crate::raw::load_capture(&p.photo, &LoadOptions::default()).map_err(|e| e.to_string())?;
    if (capture.width, capture.height) != (entry.profile.norm.width, entry.profile.norm.height) {
        return Err(format!(
            "decodes to {} × {}, not the size its header declared",
            capture.width, capture.height
        ));
    }
    let mut profile = entry.profile.clone();
    profile.allow_extrapolation = opts.allow_extrapolation;
    let model = opts.kernel_model.unwrap_or_else(|| profile.kernel_model());
    let source = ProfileKernels::with_model(profile, pick.setting, model)
        .map_err(|e| format!("{}: {e}", entry.path.display()))?
        .with_lateral(opts.lateral_colour);
    let described = crate::deblur::output::profile_described(
        &entry.path,
        pick.setting,
        model,
        source.lateral_colour(),
    );
    Ok((capture, source, described, entry.path.clone()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{GlobalModel, ModelKind};
    use crate::simulate::SimulatedSession;
    use crate::simulate::lens::VirtualLens;

    fn setting(focal_mm: f64, f_number: f64) -> LensSetting {
        LensSetting { focal_mm, f_number }
    }

    /// A profile of a 64 × 48 sensor calibrated at 24–70 mm, f/4–8, for `identity`.
    fn profile(identity: CameraIdentity) -> Profile {
        static BASE: std::sync::OnceLock<Profile> = std::sync::OnceLock::new();
        let base = BASE.get_or_init(|| {
            let settings: Vec<LensSetting> = [(24.0, 4.0), (24.0, 8.0), (70.0, 4.0), (70.0, 8.0)]
                .into_iter()
                .map(|(f, a)| setting(f, a))
                .collect();
            let ds = SimulatedSession::new(64, 48).dataset(&VirtualLens::demo(), &settings);
            let global = GlobalModel::fit(&ds, 1, 1).unwrap();
            Profile::new(
                CameraIdentity::default(),
                None,
                settings,
                Some(global),
                None,
                None,
                ModelKind::Global,
            )
            .unwrap()
        });
        Profile {
            identity,
            ..base.clone()
        }
    }

    fn id(make: &str, model: &str, lens: &str, lens_serial: Option<&str>) -> CameraIdentity {
        CameraIdentity {
            make: Some(make.into()),
            model: Some(model.into()),
            lens_model: Some(lens.into()),
            lens_serial: lens_serial.map(Into::into),
            body_serial: None,
        }
    }

    fn library(profiles: Vec<(&str, Profile)>) -> ProfileLibrary {
        let mut lib = ProfileLibrary::default();
        for (name, profile) in profiles {
            lib.add(LibraryProfile {
                path: PathBuf::from(name),
                profile,
            });
        }
        lib
    }

    fn photo(identity: CameraIdentity, f: f64, a: f64) -> PhotoFacts {
        PhotoFacts {
            width: 64,
            height: 48,
            focal_mm: Some(f),
            f_number: Some(a),
            identity,
        }
    }

    fn picked<'a>(lib: &'a ProfileLibrary, p: &PhotoFacts) -> Result<&'a str, Skip> {
        lib.pick(p, false)
            .map(|k| lib.profiles[k.index].path.to_str().unwrap())
    }

    #[test]
    fn the_lens_decides_and_the_unit_beats_its_siblings() {
        let lib = library(vec![
            ("zoom.json", profile(id("Acme", "A1", "Zoom 24-70", None))),
            ("prime.json", profile(id("Acme", "A1", "Prime 50", None))),
            (
                "zoom-7.json",
                profile(id("Acme", "A1", "Zoom 24-70", Some("7"))),
            ),
            (
                "zoom-8.json",
                profile(id("Acme", "A1", "Zoom 24-70", Some("8"))),
            ),
        ]);
        assert_eq!(
            picked(&lib, &photo(id("Acme", "A1", "Prime 50", None), 50.0, 5.6)),
            Ok("prime.json")
        );
        // The lens unit's own profile, then (another serial) the generic one.
        let unit = |s| photo(id("Acme", "A1", "Zoom 24-70", Some(s)), 35.0, 5.6);
        assert_eq!(picked(&lib, &unit("7")), Ok("zoom-7.json"));
        assert_eq!(picked(&lib, &unit(" 8 ")), Ok("zoom-8.json"));
        assert_eq!(picked(&lib, &unit("9")), Ok("zoom.json"));
        // No serial in the photo: three profiles of that lens fit, two equally best
        // (the serial ones record as much as the generic one).
        match picked(
            &lib,
            &photo(id("Acme", "A1", "Zoom 24-70", None), 35.0, 5.6),
        ) {
            Err(Skip::Ambiguous { first, second }) => {
                let names = [first, second].map(|p| p.display().to_string());
                assert!(names.iter().all(|n| n.starts_with("zoom")), "{names:?}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn photos_without_a_fitting_profile_say_why() {
        let lib = library(vec![(
            "zoom.json",
            profile(id("Acme", "A1", "Zoom 24-70", None)),
        )]);
        let other_lens = photo(id("Acme", "A1", "Tele 200", None), 50.0, 5.6);
        match picked(&lib, &other_lens) {
            Err(e @ Skip::NoProfile { .. }) => {
                assert!(e.to_string().contains("Acme A1, Tele 200"), "{e}");
            }
            other => panic!("{other:?}"),
        }
        // Another sensor size: another camera, whatever EXIF says.
        let mut cropped = photo(id("Acme", "A1", "Zoom 24-70", None), 50.0, 5.6);
        cropped.width = 32;
        assert!(matches!(
            picked(&lib, &cropped),
            Err(Skip::NoProfile { .. })
        ));
        // A photo that does not record its lens cannot be confirmed as the profile's.
        let mut no_lens = photo(id("Acme", "A1", "Zoom 24-70", None), 50.0, 5.6);
        no_lens.identity.lens_model = None;
        assert!(matches!(
            picked(&lib, &no_lens),
            Err(Skip::NoProfile { .. })
        ));
        let mut no_focal = photo(id("Acme", "A1", "Zoom 24-70", None), 50.0, 5.6);
        no_focal.focal_mm = None;
        assert_eq!(
            picked(&lib, &no_focal),
            Err(Skip::NoSettings {
                missing: "focal length"
            })
        );
    }

    #[test]
    fn settings_outside_the_calibration_skip_unless_extrapolation_is_allowed() {
        let lib = library(vec![(
            "zoom.json",
            profile(id("Acme", "A1", "Zoom 24-70", None)),
        )]);
        let far = photo(id("Acme", "A1", "Zoom 24-70", None), 105.0, 5.6);
        match lib.pick(&far, false) {
            Err(e @ Skip::OutOfRange { .. }) => assert!(e.to_string().contains("105"), "{e}"),
            other => panic!("{other:?}"),
        }
        let pick = lib.pick(&far, true).unwrap();
        assert!(pick.extrapolated);
        assert_eq!(pick.setting, setting(105.0, 5.6));
        // Of two profiles of one lens, the one calibrated for the setting wins.
        let mut tele = profile(id("Acme", "A1", "Zoom 24-70", None));
        tele.norm.focal_range_mm = [70.0, 200.0];
        for s in &mut tele.calibrated_settings {
            s.focal_mm = if s.focal_mm < 50.0 { 70.0 } else { 200.0 };
        }
        let lib = library(vec![
            ("zoom.json", profile(id("Acme", "A1", "Zoom 24-70", None))),
            ("tele.json", tele),
        ]);
        assert_eq!(picked(&lib, &far), Ok("tele.json"));
        assert_eq!(
            picked(
                &lib,
                &photo(id("Acme", "A1", "Zoom 24-70", None), 30.0, 5.6)
            ),
            Ok("zoom.json")
        );
    }

    #[test]
    fn a_profile_saved_into_a_library_replaces_its_lens_units_last_one() {
        let dir = tempfile::tempdir().unwrap();
        let lib = dir.path().join("profiles");
        let p = profile(id("Canon", "EOS 6D", "EF24-105mm f/4L", Some("42")));
        let first = ProfileLibrary::save_into(&lib, &p).unwrap();
        assert!(!first.replaced);
        let name = first
            .path
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        assert_eq!(
            name,
            "Canon EOS 6D, EF24-105mm f_4L (lens serial 42).profile.json"
        );
        let again = ProfileLibrary::save_into(&lib, &p).unwrap();
        assert_eq!(again.path, first.path);
        assert!(again.replaced && first.path.with_extension("json.previous").is_file());
        let read = ProfileLibrary::load(&lib).unwrap();
        assert_eq!(read.profiles.len(), 1, "the previous one is not read");
        assert!(read.warnings.is_empty(), "{:?}", read.warnings);
        let unnamed = profile(CameraIdentity::default());
        assert!(matches!(
            ProfileLibrary::save_into(&lib, &unnamed),
            Err(BatchError::Unnamed)
        ));
    }

    #[test]
    fn a_profile_naming_no_camera_is_left_out_with_a_warning() {
        let lib = library(vec![("anon.json", profile(CameraIdentity::default()))]);
        assert!(lib.profiles.is_empty());
        assert!(lib.warnings[0].contains("anon.json"), "{:?}", lib.warnings);
    }

    #[test]
    fn a_library_folder_skips_other_files_and_warns_of_damaged_profiles() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        profile(id("Acme", "A1", "Zoom 24-70", None))
            .save(&d.join("zoom.json"))
            .unwrap();
        std::fs::write(d.join("notes.txt"), "not a profile").unwrap();
        std::fs::write(
            d.join("session.json"),
            r#"{"schema": "lensblur.session/2"}"#,
        )
        .unwrap();
        std::fs::write(d.join("broken.json"), r#"{"schema": "lensblur.profile/1"}"#).unwrap();
        let lib = ProfileLibrary::load(d).unwrap();
        assert_eq!(lib.profiles.len(), 1);
        assert_eq!(lib.warnings.len(), 1, "{:?}", lib.warnings);
        assert!(
            lib.warnings[0].contains("broken.json"),
            "{:?}",
            lib.warnings
        );
        let empty = tempfile::tempdir().unwrap();
        assert!(matches!(
            ProfileLibrary::load(empty.path()),
            Err(BatchError::NoProfiles { .. })
        ));
    }

    fn plane_sum(c: &Capture) -> f64 {
        c.planes[0].plane.data.iter().map(|&v| f64::from(v)).sum()
    }

    /// Four RAW photos of the 64 × 48 sensor at 35 mm f/5.6, each a different scene; the
    /// third written by a `write_one` that fails, under a budget of one photo at a time
    /// and then of all at once: the same outcomes, the pixels each photo's own.
    #[test]
    fn a_pipelined_batch_keeps_each_photo_its_own_and_goes_on_past_a_failure() {
        let dir = tempfile::tempdir().unwrap();
        let who = id("Acme", "A1", "Zoom 24-70", None);
        let mut info = crate::dng::DngInfo::simulated(
            "Acme",
            "A1",
            512,
            16383,
            Some(setting(35.0, 5.6)),
            crate::dng::DngLayout::default(),
        );
        info.identity = who.clone();
        let photos: Vec<PathBuf> = (0..4)
            .map(|k| {
                let cfa: Vec<u16> = (0..64 * 48)
                    .map(|i| 600 + (i * (k + 1)) as u16 % 9000)
                    .collect();
                let path = dir.path().join(format!("p{k}.dng"));
                crate::dng::write_dng(&path, &cfa, 64, 48, &info).unwrap();
                path
            })
            .collect();
        let lib = library(vec![("zoom.json", profile(who))]);
        let one_photo = peak_bytes(64 * 48);
        for budget in [one_photo, 4 * one_photo] {
            let opts = BatchOptions {
                out_dir: dir.path().join("out"),
                memory_budget: Some(budget),
                max_parallel: Some(2),
                ..BatchOptions::default()
            };
            let planned = plan(&photos, &lib, &opts);
            let sums = Mutex::new(Vec::new());
            let report = run(
                &planned,
                &lib,
                &opts,
                &JobContext::silent(),
                &|photo, d, _, _| {
                    sums.lock()
                        .unwrap()
                        .push((photo.to_path_buf(), plane_sum(d)));
                    if photo.ends_with("p2.dng") {
                        Err("disk full".into())
                    } else {
                        Ok(())
                    }
                },
            );
            let outcomes: Vec<&Outcome> = report.outcomes.iter().map(|o| &o.outcome).collect();
            assert!(matches!(outcomes[0], Outcome::Done { .. }), "{outcomes:?}");
            assert!(matches!(outcomes[1], Outcome::Done { .. }), "{outcomes:?}");
            assert_eq!(outcomes[2], &Outcome::Failed("disk full".into()));
            assert!(matches!(outcomes[3], Outcome::Done { .. }), "{outcomes:?}");
            // Each photo written once, with its own pixels: the scenes differ, and so
            // do the sums of their deblurred planes.
            let mut sums = sums.into_inner().unwrap();
            sums.sort_by(|a, b| a.0.cmp(&b.0));
            assert_eq!(sums.len(), 4);
            for (k, a) in sums.iter().enumerate() {
                assert!(sums[k + 1..].iter().all(|b| b.1 != a.1), "{sums:?}");
            }
            for (k, (path, first)) in sums.iter().enumerate() {
                let alone = crate::raw::load_capture(path, &LoadOptions::default()).unwrap();
                let source =
                    ProfileKernels::new(lib.profiles[0].profile.clone(), setting(35.0, 5.6));
                let own =
                    deblur_capture(&alone, &source, &opts.deblur, &JobContext::silent()).unwrap();
                assert_eq!(*first, plane_sum(&own), "photo {k}");
            }
        }
    }

    #[test]
    fn memory_budget_reads_meminfo() {
        let text = "MemTotal:       24000000 kB\nMemAvailable:   1000 kB\n";
        assert_eq!(parse_mem_available(text), Some(1_024_000));
        assert_eq!(parse_mem_available("MemTotal: 5 kB\n"), None);
        assert!(peak_bytes(100_000_000) > 4_000_000_000);
    }
}
