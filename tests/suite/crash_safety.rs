//! Crash safety and concurrency of a session folder, against the files themselves.
//!
//! `lensblur calibrate` on a session measures each shot into the result cache, saves
//! `session.json` after each, and writes the profile: every kind of write a session
//! sees. Killed (SIGKILL: no destructor, no flush) at random moments, again and again,
//! the folder must each time hold every file complete or not at all, and reopen.
//! Where the kills land varies from run to run; what is checked does not.

#![cfg(unix)]

use lensblur::job::JobContext;
use lensblur::project::Project;
use lensblur::session::Session;
use lensblur::simulate::demo::{DemoSpec, make_demo};
use rand::{Rng, SeedableRng};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn calibrate(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lensblur"));
    c.args(["calibrate", "--manifest"])
        .arg(dir)
        .arg("--out")
        .arg(dir.join("profile.json"))
        .args(["--alpha", "1", "--beta", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

/// The files of the folder that are torn: present under their final name but not a
/// complete file of their format. Temporary files (a writer killed before its rename)
/// are not results and are counted apart.
fn torn_files(dir: &Path) -> (Vec<String>, usize) {
    let mut torn = Vec::new();
    let mut temporaries = 0;
    let results = dir.join(lensblur::pipeline::RESULTS_DIR);
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    if let Ok(r) = std::fs::read_dir(&results) {
        files.extend(r.flatten().map(|e| e.path()));
    }
    for p in files.iter().filter(|p| p.is_file()) {
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if lensblur::io::is_temporary(&name) {
            temporaries += 1;
            continue;
        }
        let text = std::fs::read_to_string(p).unwrap_or_default();
        let ok = if name.ends_with(".kernels.json") {
            lensblur::kernel::file::KernelsFile::from_json(&text).is_ok()
        } else if name.ends_with(".detect.json") {
            lensblur::detect::DetectFile::from_json(&text).is_ok()
        } else if name == "profile.json" {
            lensblur::profile::Profile::from_json(&text, "profile.json").is_ok()
        } else if name == "session.json" {
            Session::from_json(p, &text).is_ok()
        } else {
            true
        };
        if !ok {
            torn.push(name);
        }
    }
    (torn, temporaries)
}

#[test]
fn killed_at_random_moments_no_file_is_ever_torn() {
    let dir = tempfile::tempdir().unwrap();
    let spec = DemoSpec::grid(240, 160, &[24.0, 70.0], &[4.0, 8.0]).with_chart(6, 4);
    make_demo(dir.path(), &spec, &JobContext::silent())
        .unwrap()
        .save()
        .unwrap();

    // One whole run: it must succeed, and its length spreads the kills over a run.
    let t0 = Instant::now();
    let out = calibrate(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let whole = t0.elapsed();
    assert!(torn_files(dir.path()).0.is_empty());

    let rounds: usize = std::env::var("LENSBLUR_KILL_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(8);
    let results = dir.path().join(lensblur::pipeline::RESULTS_DIR);
    let results_of_a_run = std::fs::read_dir(&results).unwrap().count();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x6b69_6c6c);
    let (mut torn_total, mut interrupted, mut temporaries_seen) = (0, 0, 0);
    for round in 0..rounds {
        // Every other round starts from no results and is killed once a random number
        // of them are written (then a random moment later): it dies while shots are
        // measured and cached, which no clock decides. The others start with every
        // result cached and die at a random moment of the rest (session saves, the
        // fit, the profile).
        let from_scratch = round % 2 == 0;
        if from_scratch {
            let _ = std::fs::remove_dir_all(&results);
            let _ = std::fs::remove_file(dir.path().join("profile.json"));
        }
        let mut child = calibrate(dir.path()).spawn().unwrap();
        if from_scratch {
            let written = rng.random_range(0..results_of_a_run - 1);
            while child.try_wait().unwrap().is_none()
                && std::fs::read_dir(&results).map_or(0, Iterator::count) <= written
            {
                std::thread::sleep(Duration::from_millis(1));
            }
            std::thread::sleep(Duration::from_micros(rng.random_range(0..20_000)));
            if child.try_wait().unwrap().is_none() {
                interrupted += 1;
            }
        } else {
            std::thread::sleep(whole.mul_f64(rng.random_range(0.0..0.5)));
        }
        let _ = child.kill();
        let _ = child.wait();
        let (torn, temporaries) = torn_files(dir.path());
        temporaries_seen += temporaries;
        if !torn.is_empty() {
            eprintln!("round {round}: torn after a kill: {torn:?}");
        }
        torn_total += torn.len();
        // And the folder reopens: locked (the dead holder's lock went with it), swept of
        // temporaries, every result readable.
        let (mut project, opened) = Project::open(dir.path(), "the test").unwrap();
        assert_eq!(opened.swept, temporaries);
        let dropped = project.survey(&JobContext::silent()).unwrap();
        assert!(
            dropped.iter().all(|d| d.contains("pending again")),
            "{dropped:?}"
        );
        drop(project);
    }
    eprintln!(
        "{rounds} kills ({interrupted} while measuring), {temporaries_seen} temporary files swept, {torn_total} torn files"
    );
    assert_eq!(torn_total, 0);
    // The kills must have landed in the work, or the test shows nothing: a run killed
    // after fewer results than a whole run writes cannot have finished.
    assert_eq!(
        interrupted,
        rounds.div_ceil(2),
        "kills while shots were measured"
    );
    // After all of it, a whole run completes from whatever was left.
    let out = calibrate(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_second_writer_on_a_session_folder_is_refused_naming_the_holder() {
    let dir = tempfile::tempdir().unwrap();
    let spec = DemoSpec::grid(240, 160, &[24.0, 70.0], &[4.0, 8.0]).with_chart(6, 4);
    let session = make_demo(dir.path(), &spec, &JobContext::silent()).unwrap();
    session.save().unwrap();
    let (lock, _) = session.lock("the lensblur studio").unwrap();
    let out = calibrate(dir.path()).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("in use by the lensblur studio") && err.lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("profile.json").exists());
    drop(lock);
    let out = calibrate(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_folder_edited_by_hand_reopens_with_what_is_valid_and_names_what_it_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let spec = DemoSpec::grid(240, 160, &[24.0, 70.0], &[4.0, 8.0]).with_chart(6, 4);
    make_demo(dir.path(), &spec, &JobContext::silent())
        .unwrap()
        .save()
        .unwrap();
    let out = calibrate(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = Session::open(dir.path()).unwrap();
    assert!(s.shots.iter().all(|x| x.kernels.is_done()));
    let results = dir.path().join(lensblur::pipeline::RESULTS_DIR);
    let mut kernels: Vec<_> = std::fs::read_dir(&results)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().ends_with(".kernels.json"))
        .collect();
    kernels.sort();
    // One result deleted, one damaged, one shot renamed.
    std::fs::remove_file(&kernels[0]).unwrap();
    std::fs::write(&kernels[1], b"{\"schema\": \"lensblur.kernels/1\", \"wid").unwrap();
    let touched = |stem: &str| {
        kernels[..2].iter().any(|k| {
            k.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with(&format!("{stem}-"))
        })
    };
    let other = s.shots.iter().find(|x| !touched(&x.stem())).unwrap();
    let renamed = s.path_of(other);
    std::fs::rename(&renamed, renamed.with_extension("moved")).unwrap();

    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    let dropped = project.survey(&JobContext::silent()).unwrap();
    assert_eq!(with_kernels(&project), 1, "{dropped:?}");
    drop(project);
    let text = dropped.join("\n");
    assert_eq!(dropped.len(), 3, "{text}");
    assert!(text.contains("recorded kernels are gone"), "{text}");
    assert!(text.contains("measured again when needed"), "{text}");
    assert!(text.contains("not found (renamed or removed?)"), "{text}");

    // The command line says the same and measures again what it can: it calibrates
    // with the shots it has and names the one it left out; --strict stops instead.
    let out = calibrate(dir.path()).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("note: ") && err.contains("not found"), "{err}");
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("failed: ") && err.contains("1 of 4 failed"),
        "{err}"
    );
    let out = calibrate(dir.path()).arg("--strict").output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a shot is missing and --strict: {err}"
    );
    std::fs::rename(renamed.with_extension("moved"), &renamed).unwrap();
    let out = calibrate(dir.path()).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    let dropped = project.survey(&JobContext::silent()).unwrap();
    assert!(dropped.is_empty(), "{dropped:?}");
    assert_eq!(with_kernels(&project), 4);
}

fn with_kernels(project: &Project) -> usize {
    project
        .shots()
        .filter(|s| s.state.kernels.is_some())
        .count()
}
