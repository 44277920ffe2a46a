//! `lensblur calibrate`: fit blur models over a calibration session and write a profile.
//!
//! The session is either a manifest of shots, each measured through the core pipeline
//! (load, detect, kernels; every stage's result cached in `results/` beside the
//! manifest, the same cache the studio keeps, so shots measured there or in an earlier
//! run are not measured again), or a list of kernels files measured earlier.

use super::common::{StageClock, load_chart, progress_job, progress_job_timed, write_json};
use anyhow::Result;
use lensblur::calibrate::{CalibrateOptions, Families, calibrate};
use lensblur::chart::ChartSpec;
use lensblur::crossval::{CvOptions, HoldOut, ShapeCriterion, ShapeCvOptions};
use lensblur::job::JobContext;
use lensblur::model::{Dataset, LocalOptions, ModelKind};
use lensblur::pipeline::GivenSetting;
use lensblur::plane::LensSetting;
use lensblur::profile::trust::LARGE_ERROR_PCT;
use lensblur::project::{MeasurePlan, Project, ShotEvent, Stages};
use lensblur::session::ShotId;
use std::path::{Path, PathBuf};

/// Where a session's measurements come from (shared by calibrate, crossval, sweeps).
#[derive(clap::Args, Default, Clone)]
pub struct SessionArgs {
    /// The session: a folder of shots (RAW, TIFF, PNG, JPEG; the settings from their
    /// EXIF, the manifest inferred written there for the next run), a studio session
    /// folder, or a manifest.
    #[arg(conflicts_with_all = ["manifest", "kernels"])]
    pub session: Option<PathBuf>,
    /// Session manifest (or a studio session folder or its session.json); every shot
    /// is measured, or taken from the cache in results/ beside it.
    #[arg(long, conflicts_with = "kernels")]
    pub manifest: Option<PathBuf>,
    /// Kernels files (lensblur.kernels/1), one per shot, instead of a manifest.
    #[arg(long, num_args = 1..)]
    pub kernels: Vec<PathBuf>,
    /// Chart spec, where another chart than the manifest's (or the default 24×16) was
    /// printed.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Measure every shot again, ignoring (and replacing) cached results.
    #[arg(long)]
    pub no_cache: bool,
    /// Stop when any shot fails, instead of listing the failed shots and going on
    /// with the others.
    #[arg(long)]
    pub strict: bool,
}

/// Loads a session's measured Gaussians, measuring (or taking from the cache) every
/// shot of a manifest, for the command `who` (which has no `--focal`/`--aperture`).
pub fn load_session(args: &SessionArgs, who: &str) -> Result<(Dataset, Option<ChartSpec>)> {
    load_session_locked(args, who, None).map(|(ds, chart, _)| (ds, chart))
}

/// [`load_session`], returning the project (which holds the session folder's lock)
/// for a caller that goes on writing there.
/// `given` is the setting of every shot of a plain folder of shots (see
/// [`measure_project`]), `None` for a command without `--focal` and `--aperture`.
pub fn load_session_locked(
    args: &SessionArgs,
    who: &str,
    given: Option<GivenSetting>,
) -> Result<(Dataset, Option<ChartSpec>, Option<Project>)> {
    let Some(manifest_path) = args.session.as_ref().or(args.manifest.as_ref()) else {
        if args.kernels.is_empty() {
            anyhow::bail!(
                "which session? give a folder of shots or a session folder ({who} DIR), --manifest (a manifest), or --kernels (kernels files, one per shot)"
            );
        }
        let mut chart = None;
        if args.chart.is_some() {
            chart = Some(load_chart(args.chart.as_deref())?);
        }
        let paths: Vec<&Path> = args.kernels.iter().map(PathBuf::as_path).collect();
        return Ok((Dataset::from_kernels_files(&paths, &[])?, chart, None));
    };
    let chart = match &args.chart {
        Some(_) => Some(load_chart(args.chart.as_deref())?),
        None => None,
    };
    let plan = MeasurePlan {
        require_setting: true,
        ..MeasurePlan::missing(Stages::All)
    };
    let project = measure_project(
        manifest_path,
        who,
        chart,
        args.no_cache,
        plan,
        args.strict,
        given,
    )?;
    let ds = lensblur::pipeline::dataset(&project.measured_shots())?;
    let chart = project.session().chart.clone();
    Ok((ds, Some(chart), Some(project)))
}

/// Opens the session or manifest at `path` as a project (a plain folder of shots
/// becomes one: see [`take_in_folder`]), surveys it, and measures what `plan` asks
/// (every shot again with `again`), printing each shot's events. Every shot
/// is tried; those that fail are listed afterwards, one line each with its own reason,
/// and left out. Fails when none is left, or (with `strict`) when any failed. `given`
/// is `None` for a command without `--focal` and `--aperture`.
pub fn measure_project(
    path: &Path,
    who: &str,
    chart: Option<ChartSpec>,
    again: bool,
    plan: MeasurePlan,
    strict: bool,
    given: impl Into<Option<GivenSetting>>,
) -> Result<Project> {
    let given = given.into();
    let (mut project, opened) = Project::open(path, who)?;
    if opened.swept > 0 {
        eprintln!(
            "{}: removed {} unfinished temporary files left by an interrupted write",
            project.folder().display(),
            opened.swept
        );
    }
    if let Some(chart) = chart {
        project.session_mut().chart = chart;
    }
    if project.session().shots.is_empty() && path.is_dir() {
        take_in_folder(&mut project, given)?;
    }
    if project.session().shots.is_empty() {
        if path.is_dir() {
            anyhow::bail!(
                "{}: no shots in this folder (RAW, TIFF, PNG or JPEG files), and no manifest",
                path.display()
            );
        }
        anyhow::bail!("{}: the manifest lists no shots", path.display());
    }
    // A shot that cannot be read is listed once, among the failures, not here too.
    let notes = project.survey(&JobContext::silent())?;
    let unreadable: Vec<String> = project
        .shots()
        .filter_map(|s| s.state.unreadable.clone())
        .collect();
    for line in notes {
        if !unreadable.iter().any(|why| line.starts_with(why.as_str())) {
            eprintln!("note: {line}");
        }
    }
    let plan = if again {
        let ids = project.shots().map(|s| s.shot.id).collect();
        MeasurePlan {
            only: Some(ids),
            ..plan
        }
    } else {
        plan
    };
    let job = project.measure_job(&plan);
    let cached = if again {
        0
    } else {
        project
            .shots()
            .filter(|s| s.state.kernels.is_some())
            .count()
    };
    // A shot that cannot be read is listed with those that fail while measured.
    let mut failures: Vec<(ShotId, String)> = project
        .shots()
        .filter_map(|s| Some((s.shot.id, s.state.unreadable.clone()?)))
        .collect();
    let mut measured = 0;
    let mut save_failed = None;
    let ctx = progress_job();
    job.run(&ctx, &|_| Some(ctx.clone()), &mut |event| {
        project.record(&event);
        if let Some(line) = describe_event(&project, &event) {
            eprintln!("{line}");
        }
        match &event {
            ShotEvent::Measured { .. } => measured += 1,
            ShotEvent::Failed { id, reason, .. } if failures.iter().all(|(f, _)| f != id) => {
                failures.push((*id, reason.clone()));
            }
            _ => {}
        }
        // Each shot's status is saved as it is measured, so the studio opens the
        // session with the work done even if this run is stopped.
        if let Err(e) = project.save() {
            save_failed.get_or_insert(e);
        }
    })
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    project.flush()?;
    if let Some(e) = save_failed {
        return Err(e.into());
    }
    let usable = project
        .shots()
        .filter(|s| failures.iter().all(|(id, _)| *id != s.shot.id))
        .filter(|s| s.state.kernels.is_some() || s.state.detection.is_some())
        .count();
    let total = project.session().shots.len();
    // A run that stops on one failed shot says so in one line: the shot and why.
    if let [(_, reason)] = failures.as_slice()
        && (strict || usable == 0)
    {
        anyhow::bail!("{reason}");
    }
    report_failures(&project, &failures);
    match failures.len() {
        0 => eprintln!("{measured} shots measured, {cached} from the cache"),
        n if strict => {
            anyhow::bail!("{n} of {total} shots failed (listed above); stopped by --strict")
        }
        n if usable == 0 => {
            anyhow::bail!("all {n} shots failed (listed above): nothing to go on with")
        }
        n => eprintln!(
            "{measured} shots measured, {cached} from the cache; {n} of {total} failed and left out (--strict stops instead)"
        ),
    }
    Ok(project)
}

/// A plain folder of shots as the session: its shots taken in, with the settings their
/// EXIF records (or `given`, for all), and the manifest inferred written beside them
/// for the next run (and for editing, where EXIF was wrong).
fn take_in_folder(project: &mut Project, given: Option<GivenSetting>) -> Result<()> {
    let taken = project.take_in_folder(given.unwrap_or_default())?;
    let folder = project.folder().display().to_string();
    if !taken.skipped.is_empty() {
        eprintln!(
            "{folder}: skipped {} (not shots: RAW, TIFF, PNG or JPEG)",
            taken.skipped.join(", ")
        );
    }
    if taken.added == 0 {
        return Ok(());
    }
    if !taken.no_setting.is_empty() {
        eprintln!(
            "{folder}: no focal length or aperture in the EXIF of {} ({})",
            taken.no_setting.join(", "),
            if given.is_some() {
                "give --focal and --aperture, or write them in the manifest"
            } else {
                "write them in the manifest written there"
            }
        );
    }
    let manifest = project.session().write_manifest()?;
    let given = given.unwrap_or_default();
    let from = match (given.focal_mm, given.f_number) {
        (Some(_), Some(_)) => "the settings given",
        (None, None) => "settings from EXIF",
        _ => "settings given and from EXIF",
    };
    eprintln!(
        "{folder}: no manifest: took in {} shots ({from}); wrote {} for the next run",
        taken.added,
        manifest.display()
    );
    Ok(())
}

/// Lists every failed shot, one line each with its own reason, then what the session
/// loses with them: each setting no shot is left at, and each setting left with fewer
/// shots (fewer frame positions; the coverage notes say which parts of the frame).
fn report_failures(project: &Project, failures: &[(ShotId, String)]) {
    for (_, reason) in failures {
        eprintln!("failed: {reason}");
    }
    let failed = |id: ShotId| failures.iter().any(|(f, _)| *f == id);
    let setting_of = |s: &lensblur::project::ProjectShot<'_>| {
        let k = s.state.kernels.as_deref();
        Some(LensSetting {
            focal_mm: s.shot.focal_mm.or(k.and_then(|k| k.focal_mm))?,
            f_number: s.shot.f_number.or(k.and_then(|k| k.f_number))?,
        })
    };
    let mut lost: Vec<(LensSetting, Vec<String>)> = Vec::new();
    for s in project.shots().filter(|s| failed(s.shot.id)) {
        let Some(setting) = setting_of(&s) else {
            continue;
        };
        match lost.iter_mut().find(|(l, _)| l.same_as(setting)) {
            Some((_, names)) => names.push(s.shot.name()),
            None => lost.push((setting, vec![s.shot.name()])),
        }
    }
    for (setting, names) in lost {
        let kept = project
            .shots()
            .filter(|s| !failed(s.shot.id))
            .filter(|s| setting_of(s).is_some_and(|k| k.same_as(setting)))
            .count();
        let names = names.join(", ");
        if kept == 0 {
            eprintln!("lost: no shot left at {setting} (with {names})");
        } else {
            let shots = if kept == 1 { "shot" } else { "shots" };
            eprintln!(
                "lost: {setting} keeps {kept} {shots} without {names}: fewer positions in the frame"
            );
        }
    }
}

/// One line for a shot's event, as the command line prints it; `None` for events it
/// leaves to the progress bar.
fn describe_event(project: &Project, event: &ShotEvent) -> Option<String> {
    let name = project
        .session()
        .shot(event.shot())
        .map_or_else(|| event.shot().to_string(), lensblur::session::Shot::name);
    match event {
        ShotEvent::Detected { detection, .. } => Some(format!(
            "{name}: {}",
            lensblur::project::detect_summary(detection)
        )),
        ShotEvent::Measured { kernels, .. } => Some(format!(
            "{name}: {}",
            lensblur::project::kernels_summary(kernels)
        )),
        ShotEvent::Cancelled { .. } => Some(format!("{name}: cancelled")),
        ShotEvent::Started { .. } | ShotEvent::Failed { .. } => None,
    }
}

#[derive(clap::Args, Default)]
pub struct Args {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Where to write the profile (lensblur.profile/4).
    #[arg(long)]
    pub out: PathBuf,
    /// With a folder of shots and no manifest: every shot's focal length in mm,
    /// instead of its EXIF's.
    #[arg(long)]
    pub focal: Option<f64>,
    /// With a folder of shots and no manifest: every shot's aperture as an f-number,
    /// instead of its EXIF's.
    #[arg(long)]
    pub aperture: Option<f64>,
    /// Which models to fit.
    #[arg(long, value_enum, default_value = "both")]
    pub model: ModelArg,
    /// Spatial order α (skips cross-validated selection).
    #[arg(long)]
    pub alpha: Option<usize>,
    /// Order β in focal length and aperture (must stay below min(N_f, N_a)).
    #[arg(long)]
    pub beta: Option<usize>,
    /// Cross-validation folds (10: hold out 10 % of the shots per fold).
    #[arg(long, default_value_t = 10)]
    pub folds: usize,
    /// Local model radius in pixels (default: 3× the largest imaged square).
    #[arg(long)]
    pub radius_px: Option<f64>,
    /// What a cross-validation fold holds out.
    #[arg(long, value_enum, default_value = "shot")]
    pub hold_out: HoldOutArg,
    /// Also write the cross-validation report here.
    #[arg(long)]
    pub cv_out: Option<PathBuf>,
    /// Fit no kernel-shape model (by default one is cross-validated from the measured
    /// kernels and kept where its held-out kernels deblur better than the Gaussians').
    #[arg(long)]
    pub no_shape_model: bool,
    /// What the kernel-shape model is chosen by: the error its held-out kernels leave
    /// in a deblurred photo, or their relative L2.
    #[arg(long, value_enum, default_value = "restoration")]
    pub shape_criterion: ShapeCriterionArg,
}

/// What the kernel-shape model is chosen by.
#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum ShapeCriterionArg {
    /// The RMS error the held-out kernels leave in a deblurred photo.
    #[default]
    Restoration,
    /// The held-out kernels' relative L2.
    L2,
}

impl From<ShapeCriterionArg> for ShapeCriterion {
    fn from(c: ShapeCriterionArg) -> Self {
        match c {
            ShapeCriterionArg::Restoration => ShapeCriterion::Restoration,
            ShapeCriterionArg::L2 => ShapeCriterion::HeldOutL2,
        }
    }
}

/// What a cross-validation fold holds out.
#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum HoldOutArg {
    /// Whole shots, each on its own (the paper's holdout).
    #[default]
    Shot,
    /// Every shot of a setting together: each fold predicts unseen settings.
    Setting,
}

impl From<HoldOutArg> for HoldOut {
    fn from(h: HoldOutArg) -> Self {
        match h {
            HoldOutArg::Shot => HoldOut::Shot,
            HoldOutArg::Setting => HoldOut::Setting,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Default, PartialEq, Eq)]
pub enum ModelArg {
    Global,
    Local,
    #[default]
    Both,
}

impl From<ModelArg> for Families {
    fn from(m: ModelArg) -> Self {
        match m {
            ModelArg::Global => Families::Global,
            ModelArg::Local => Families::Local,
            ModelArg::Both => Families::Both,
        }
    }
}

pub fn run(args: Args) -> Result<()> {
    for out in std::iter::once(&args.out).chain(&args.cv_out) {
        super::common::check_out_folder(out)?;
    }
    let t0 = std::time::Instant::now();
    // The folder stays locked until the profile is written (it may be written there).
    super::common::check_setting_args(args.focal, args.aperture)?;
    let given = GivenSetting {
        focal_mm: args.focal,
        f_number: args.aperture,
    };
    let (ds, chart, _project) =
        load_session_locked(&args.session, "lensblur calibrate", Some(given))?;
    // A small chart shot at several positions: say which parts of the frame a setting's
    // shots left out, before the models are fitted to what there is.
    for c in lensblur::review::coverage_of_dataset(&ds) {
        if let Some(line) = c.missing_line() {
            eprintln!("note: {line}");
        }
    }
    let opts = CalibrateOptions {
        families: args.model.into(),
        alpha: args.alpha,
        beta: args.beta,
        cv: CvOptions {
            folds: args.folds,
            hold_out: args.hold_out.into(),
            local: LocalOptions {
                radius_px: args.radius_px,
                ..LocalOptions::default()
            },
            ..CvOptions::default()
        },
        shape: (!args.no_shape_model).then(|| ShapeCvOptions {
            criterion: args.shape_criterion.into(),
            ..ShapeCvOptions::default()
        }),
    };
    let loaded = std::time::Instant::now();
    let clock = StageClock::default();
    let (profile, report) = calibrate(&ds, chart, &opts, &progress_job_timed(Some(clock.clone())))?;
    let modelled = std::time::Instant::now();
    profile.save(&args.out)?;
    if let (Some(p), Some(r)) = (&args.cv_out, &report) {
        write_json(p, r)?;
    }
    eprintln!("{}", verdict(&profile, ds.shots.len()));
    let describe = |k: &str, a: usize, b: usize, cv: Option<f64>| {
        let e = cv
            .map(|e| format!(", CV error {e:.2} % of range"))
            .unwrap_or_default();
        eprintln!("{k} model: α = {a}, β = {b}{e}");
    };
    if let Some(g) = &profile.global {
        describe(
            "global",
            g.alpha,
            g.beta,
            profile
                .cv
                .as_ref()
                .and_then(|c| c.global.as_ref())
                .map(|p| p.mean_pct),
        );
    }
    if let Some(l) = &profile.local {
        describe(
            "local",
            l.alpha,
            l.beta,
            profile
                .cv
                .as_ref()
                .and_then(|c| c.local.as_ref())
                .map(|p| p.mean_pct),
        );
    }
    if let Some(cv) = &profile.shape_cv {
        eprintln!("{}", shape_summary(cv));
    }
    if let Some(place) = &profile.place {
        eprintln!("{}", place_summary(place));
    }
    eprintln!(
        "{} shots, {} samples; profile {} written in {:.1} s",
        ds.shots.len(),
        ds.samples.len(),
        args.out.display(),
        t0.elapsed().as_secs_f64()
    );
    eprintln!(
        "{}",
        timings(
            loaded.duration_since(t0).as_secs_f64(),
            &clock.durations(modelled),
            modelled.elapsed().as_secs_f64()
        )
    );
    Ok(())
}

/// The profile in a sentence: how well its preferred model predicts the blur of shots
/// it was not fitted to, against what this method reaches and the error above which
/// the profile warns ([`LARGE_ERROR_PCT`]).
fn verdict(profile: &lensblur::profile::Profile, shots: usize) -> String {
    let cv = profile.cv.as_ref().and_then(|c| match profile.preferred {
        ModelKind::Global => c.global.as_ref(),
        ModelKind::Local => c.local.as_ref(),
    });
    let Some(cv) = cv.filter(|c| c.mean_pct.is_finite()) else {
        return format!(
            "The profile was fitted to {shots} shot{} and nothing held out to check it against: trust it only at the settings it was shot at.",
            if shots == 1 { "" } else { "s" }
        );
    };
    let e = cv.mean_pct;
    let how = if e <= 3.0 {
        "good: as close as this method gets (1.4–3 % is typical)".to_string()
    } else if e <= LARGE_ERROR_PCT {
        "usable, though above the typical 1.4–3 %: more shots, or sharper and evenly lit ones, would tighten it".to_string()
    } else {
        format!(
            "poor (above {LARGE_ERROR_PCT} %): the shots and the model disagree (noisy kernels, a shot unlike its neighbours, too few squares): check the shots' focus and light, and shoot again where they fall short"
        )
    };
    format!(
        "The profile predicts the blur of shots it was not fitted to within {e:.1} % of its range on average ({shots} shots, cross-validated): {how}."
    )
}

/// Where the run's time went: the session's measurements (or the cache), the Gaussian
/// models (their cross-validation and fits), the kernel shapes, and the writing.
fn timings(load_s: f64, stages: &[(String, f64)], write_s: f64) -> String {
    let stage = |name: &str| {
        stages
            .iter()
            .find(|(s, _)| s == name)
            .map_or(0.0, |(_, t)| *t)
    };
    let shapes = stage("kernel shapes");
    let gaussian: f64 = stages.iter().map(|(_, t)| t).sum::<f64>() - shapes;
    format!(
        "timings: shots {load_s:.1} s; Gaussian models {gaussian:.1} s (global CV {:.1}, local CV {:.1}, fits {:.1}); kernel shapes {shapes:.1} s; writing {write_s:.1} s",
        stage("global CV"),
        stage("local CV"),
        stage("fitting"),
    )
}

/// One line on where the kernels sit: the place model's orders and held-out error.
fn place_summary(place: &lensblur::model::PlaceModel) -> String {
    match place
        .cv
        .iter()
        .find(|c| (c.alpha, c.beta) == (place.alpha, place.beta))
    {
        Some(c) => format!(
            "kernel place: α = {}, β = {}: held-out {:.3} px against {:.3} px with every kernel centred",
            place.alpha, place.beta, c.rms_px, place.centred_rms_px
        ),
        None => format!(
            "kernel place: α = {}, β = {} (no shot to hold out); the kernels' centroids lie {:.3} px RMS from their pixels",
            place.alpha, place.beta, place.centred_rms_px
        ),
    }
}

/// One line on the kernel-shape model's cross-validation: what was kept and why.
fn shape_summary(cv: &lensblur::crossval::ShapeCvReport) -> String {
    let said = |p: &lensblur::crossval::ShapeCvPoint| cv.criterion.describe(p);
    let gauss = said(&cv.gaussian);
    let verdict = match (&cv.best_shape, cv.shape_chosen) {
        (Some(b), true) => format!(
            "kernel shapes: {} component{}, α = {}, β = {}: held-out {} against {gauss} for the Gaussians alone ({} kernels)",
            b.components,
            if b.components == 1 { "" } else { "s" },
            b.alpha,
            b.beta,
            said(b),
            cv.kernels
        ),
        (Some(b), false) => format!(
            "kernel shapes: not kept: the best ({} components) predicts held-out kernels no better than the Gaussians ({} against {gauss})",
            b.components,
            said(b)
        ),
        (None, _) => {
            format!("kernel shapes: none fitted; the Gaussians' held-out kernels give {gauss}")
        }
    };
    // Where held-out L2 alone would have chosen otherwise, say so: the two rank
    // models differently on lenses whose kernels are far from Gaussian.
    match (&cv.best_shape, &cv.best_by_l2) {
        (Some(b), Some(l2))
            if cv.criterion != ShapeCriterion::HeldOutL2
                && (b.components, b.alpha, b.space) != (l2.components, l2.alpha, l2.space) =>
        {
            format!(
                "{verdict}; held-out L2 alone would choose {} component{}, α = {} ({})",
                l2.components,
                if l2.components == 1 { "" } else { "s" },
                l2.alpha,
                said(l2)
            )
        }
        _ => verdict,
    }
}
