//! The fuzz targets: every reader of a file a user hands lensblur, each as a function
//! of the file's bytes that must return (with `Ok` or an error) for any input, never
//! panic, hang or allocate past [`crate::limits`].
//!
//! The coverage-guided fuzzer drives them from `fuzz/` (one binary per target, see
//! `scripts/fuzz.sh`); the test suite runs each over its seed corpus, the findings
//! kept as regressions, and a bounded set of mutations of them, so a target that
//! regresses fails CI without the fuzzer installed.

use crate::plane::Channel;
use std::path::Path;

/// One reader under test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// Our DNG/TIFF directory parser, our uncompressed strip and tile reader, and the
    /// RAW decoder behind them (lossless JPEG): a RAW file's bytes into CFA planes.
    Dng,
    /// The whole load path: format sniffing, RAW, PNG, TIFF and JPEG decoding, EXIF.
    Load,
    /// EXIF extraction (settings and camera identity).
    Exif,
    /// A chart spec file.
    Chart,
    /// A session manifest.
    Manifest,
    /// A kernels file, and the kernel field deblurring builds from it.
    Kernels,
    /// A detection file, and the detection it becomes.
    Detect,
    /// A lens profile, and a prediction from it.
    Profile,
    /// A `session.json` (or a manifest opened as a session).
    Session,
}

impl Target {
    pub const ALL: [Target; 9] = [
        Target::Dng,
        Target::Load,
        Target::Exif,
        Target::Chart,
        Target::Manifest,
        Target::Kernels,
        Target::Detect,
        Target::Profile,
        Target::Session,
    ];

    /// The target's name: its fuzz binary and its corpus folder.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Target::Dng => "dng",
            Target::Load => "load",
            Target::Exif => "exif",
            Target::Chart => "chart",
            Target::Manifest => "manifest",
            Target::Kernels => "kernels",
            Target::Detect => "detect",
            Target::Profile => "profile",
            Target::Session => "session",
        }
    }

    /// Reads `data` as this target's file, and uses what it read as the program would.
    /// Returns whether the file was accepted (for corpus statistics; any answer is a
    /// pass, a panic is the failure).
    #[must_use]
    pub fn run(self, data: &[u8]) -> bool {
        let text = || std::str::from_utf8(data).ok();
        match self {
            Target::Dng => crate::raw::decode_raw(Path::new("fuzz.dng"), data).is_ok(),
            Target::Load => crate::raw::decode_capture(
                Path::new("fuzz"),
                data,
                &crate::raw::LoadOptions::default(),
            )
            .is_ok(),
            Target::Exif => crate::raw::read_exif(data) != crate::raw::ExifInfo::default(),
            Target::Chart => text().is_some_and(|t| {
                crate::chart::ChartSpec::from_json("fuzz", t)
                    .map(|spec| spec.paper_mm())
                    .is_ok()
            }),
            Target::Manifest => text().is_some_and(|t| {
                crate::manifest::Manifest::from_json(Path::new("fuzz/manifest.json"), t)
                    .and_then(|m| {
                        m.chart_spec(Path::new("fuzz")).map_err(|e| {
                            crate::manifest::ManifestError::Parse {
                                path: "fuzz".into(),
                                reason: e.to_string(),
                            }
                        })
                    })
                    .is_ok()
            }),
            Target::Kernels => text().is_some_and(|t| {
                let Ok(file) = crate::kernel::file::KernelsFile::from_json(t) else {
                    return false;
                };
                let (w, h) = (file.width as f64, file.height as f64);
                let Ok(field) = crate::deblur::source::ScatteredKernels::checked(
                    file,
                    crate::deblur::source::Prefer::Kernel,
                    "fuzz",
                ) else {
                    return false;
                };
                use crate::deblur::source::KernelSource;
                field.kernel_at(Channel::G, w / 2.0, h / 2.0).is_ok()
            }),
            Target::Detect => text().is_some_and(|t| {
                crate::detect::DetectFile::from_json(t)
                    .map(|f| crate::detect::Detection::from_file(&f))
                    .is_ok()
            }),
            Target::Profile => text().is_some_and(|t| {
                let Ok(p) = crate::profile::Profile::from_json(t, "fuzz") else {
                    return false;
                };
                let Some(&setting) = p.calibrated_settings.first() else {
                    return false;
                };
                let (w, h) = (p.norm.width as f64, p.norm.height as f64);
                p.channels()
                    .into_iter()
                    .all(|c| p.predict(c, w / 3.0, h / 2.0, setting).is_ok())
            }),
            Target::Session => text().is_some_and(|t| {
                crate::session::Session::from_json(Path::new("fuzz/session.json"), t)
                    .and_then(|s| {
                        serde_json::to_vec(&s.manifest()).map_err(|e| {
                            crate::session::SessionError::Parse {
                                path: "fuzz".into(),
                                reason: e.to_string(),
                            }
                        })
                    })
                    .is_ok()
            }),
        }
    }
}

/// Deterministic mutations of an input, as the fuzzer's first stages make them: bit
/// flips, interesting bytes, truncations, duplications, and numbers in text made
/// extreme. `n` mutants for a seed, made one at a time as they are asked for (a run of
/// 10⁵ mutants of a 100 kB file would not fit in memory at once).
pub fn mutants(seed: &[u8], n: usize, rng_seed: u64) -> impl Iterator<Item = Vec<u8>> + '_ {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(rng_seed);
    const INTERESTING: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, b'-', b'9', b'"'];
    const NUMBERS: [&[u8]; 7] = [
        b"0",
        b"-1",
        b"1e308",
        b"4294967295",
        b"18446744073709551616",
        b"NaN",
        b"0.0000001",
    ];
    (0..n).map(move |_| {
        let mut m = seed.to_vec();
        if m.is_empty() {
            return vec![rng.random()];
        }
        for _ in 0..rng.random_range(1..=4) {
            let at = rng.random_range(0..m.len().max(1));
            match rng.random_range(0..6) {
                0 => m[at] ^= 1 << rng.random_range(0..8),
                1 => m[at] = INTERESTING[rng.random_range(0..INTERESTING.len())],
                2 => m.truncate(at.max(1)),
                3 => {
                    let end = (at + rng.random_range(1..64)).min(m.len());
                    let chunk = m[at..end].to_vec();
                    m.splice(at..at, chunk);
                }
                4 => {
                    // Replace the number starting here (text formats) with an extreme.
                    let end = m[at..]
                        .iter()
                        .position(|b| !(b.is_ascii_digit() || *b == b'.' || *b == b'-'))
                        .map_or(m.len(), |k| at + k);
                    let with = NUMBERS[rng.random_range(0..NUMBERS.len())];
                    m.splice(at..end, with.iter().copied());
                }
                _ => {
                    // A 32-bit field of a binary header set to an extreme.
                    let v: u32 = [0, 1, 0xffff, 0x7fff_ffff, u32::MAX][rng.random_range(0..5)];
                    for (k, b) in v.to_le_bytes().into_iter().enumerate() {
                        if let Some(x) = m.get_mut(at + k) {
                            *x = b;
                        }
                    }
                }
            }
            if m.is_empty() {
                break;
            }
        }
        m
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutants_are_deterministic_and_differ_from_their_seed() {
        let seed = br#"{"schema":"lensblur.chart/1","cols":12}"#;
        let a: Vec<Vec<u8>> = mutants(seed, 50, 1).collect();
        assert_eq!(a, mutants(seed, 50, 1).collect::<Vec<_>>());
        assert!(a.iter().filter(|m| m.as_slice() != seed).count() > 40);
    }
}
