//! The calibration project every front end drives: surveyed once, measured as a job
//! of per-shot events, each shot file fingerprinted once per run, saved off the
//! caller's thread, calibrated from what it holds.

use lensblur::job::JobContext;
use lensblur::project::{MeasurePlan, Project, ShotEvent, Stages};
use lensblur::session::{Session, ShotId, StageStatus};
use lensblur::shot_file::times_read;
use lensblur::simulate::demo::{DemoSpec, make_demo};

fn small_demo(dir: &std::path::Path) -> Session {
    let spec = DemoSpec::grid(240, 160, &[24.0, 70.0], &[4.0, 8.0]).with_chart(6, 4);
    let s = make_demo(dir, &spec, &JobContext::silent()).unwrap();
    s.save().unwrap();
    s
}

fn run(project: &mut Project, plan: &MeasurePlan) -> Vec<ShotEvent> {
    let job = project.measure_job(plan);
    let ctx = JobContext::silent();
    let mut events = Vec::new();
    job.run(&ctx, &|_| Some(ctx.clone()), &mut |e| events.push(e))
        .unwrap();
    for e in &events {
        assert!(project.record(e));
    }
    events
}

#[test]
fn each_shot_is_read_once_per_run_and_its_events_tell_what_happened() {
    let dir = tempfile::tempdir().unwrap();
    let session = small_demo(dir.path());
    let paths: Vec<_> = session.shots.iter().map(|s| session.path_of(s)).collect();
    let reads = || paths.iter().map(|p| times_read(p)).collect::<Vec<_>>();
    assert_eq!(reads(), vec![0; 4]);

    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    assert!(project.survey(&JobContext::silent()).unwrap().is_empty());
    assert_eq!(reads(), vec![1; 4], "the survey reads each shot once");

    // Detection alone, then kernels: neither reads a shot file again.
    let events = run(&mut project, &MeasurePlan::missing(Stages::Detect));
    assert_eq!(
        reads(),
        vec![1; 4],
        "detection reuses the survey's fingerprints"
    );
    let detected = events
        .iter()
        .filter(|e| matches!(e, ShotEvent::Detected { .. }))
        .count();
    assert_eq!(detected, 4, "{events:?}");
    assert!(
        project
            .shots()
            .all(|s| s.shot.detect.is_done() && s.state.detection.is_some())
    );
    let events = run(&mut project, &MeasurePlan::missing(Stages::Kernels));
    assert_eq!(reads(), vec![1; 4]);
    // Each shot: started, then measured, in session order.
    let order: Vec<(ShotId, &str)> = events
        .iter()
        .map(|e| {
            let kind = match e {
                ShotEvent::Started { .. } => "started",
                ShotEvent::Measured { .. } => "measured",
                _ => "other",
            };
            (e.shot(), kind)
        })
        .collect();
    let ids: Vec<ShotId> = project.session().shots.iter().map(|s| s.id).collect();
    let expected: Vec<(ShotId, &str)> = ids
        .iter()
        .flat_map(|&id| [(id, "started"), (id, "measured")])
        .collect();
    assert_eq!(order, expected);
    // Nothing is left to measure, and nothing is read for it.
    assert!(
        project
            .measure_job(&MeasurePlan::missing(Stages::All))
            .is_empty()
    );

    // Saved off this thread; once flushed, the file says what the project holds.
    project.save().unwrap();
    project.flush().unwrap();
    let on_disk = Session::open(dir.path()).unwrap();
    assert!(
        on_disk
            .shots
            .iter()
            .all(|s| s.detect.is_done() && s.kernels.is_done())
    );

    // Calibration from what the project holds.
    let cal = project
        .calibration_job(lensblur::calibrate::CalibrateOptions {
            alpha: Some(1),
            beta: Some(1),
            shape: None,
            ..Default::default()
        })
        .unwrap()
        .run(&JobContext::silent())
        .unwrap();
    assert_eq!(cal.dataset.shots.len(), 4);
    drop(project);

    // A new run reads each file once more, and finds everything in the cache.
    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    project.survey(&JobContext::silent()).unwrap();
    assert_eq!(reads(), vec![2; 4]);
    assert!(project.shots().all(|s| s.state.kernels.is_some()));
    assert!(
        project
            .measure_job(&MeasurePlan::missing(Stages::All))
            .is_empty()
    );
}

#[test]
fn a_removed_shot_is_skipped_and_its_late_events_dropped_and_failures_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let session = small_demo(dir.path());
    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    project.survey(&JobContext::silent()).unwrap();
    let ids: Vec<ShotId> = session.shots.iter().map(|s| s.id).collect();

    // The job is planned, then one shot removed: the job skips it (its part is gone),
    // and an event that still names it is not recorded.
    let job = project.measure_job(&MeasurePlan::again(Stages::Detect, ids[..2].to_vec()));
    assert_eq!(job.shots(), ids[..2].to_vec());
    project.remove_shot(ids[0]);
    let ctx = JobContext::silent();
    let removed = ids[0];
    let mut events = Vec::new();
    job.run(&ctx, &|id| (id != removed).then(|| ctx.clone()), &mut |e| {
        events.push(e)
    })
    .unwrap();
    assert!(events.iter().all(|e| e.shot() == ids[1]), "{events:?}");
    assert!(!project.record(&ShotEvent::Cancelled { id: removed }));

    // A shot whose file went fails with a reason naming the file, recorded.
    let gone = project
        .session()
        .path_of(project.session().shot(ids[2]).unwrap());
    std::fs::remove_file(&gone).unwrap();
    let job = project.measure_job(&MeasurePlan::again(Stages::All, vec![ids[2]]));
    let mut events = Vec::new();
    job.run(&ctx, &|_| Some(ctx.clone()), &mut |e| events.push(e))
        .unwrap();
    let failed = events
        .iter()
        .find_map(|e| match e {
            ShotEvent::Failed { reason, .. } => Some(reason.clone()),
            _ => None,
        })
        .expect("a failure");
    assert!(failed.contains(&gone.display().to_string()), "{failed}");
    for e in &events {
        project.record(e);
    }
    assert!(matches!(
        project.session().shot(ids[2]).unwrap().detect,
        StageStatus::Failed { .. }
    ));

    // A cancelled job ends with an error, the shot it was on reported cancelled.
    let job = project.measure_job(&MeasurePlan::again(Stages::Detect, vec![ids[1]]));
    let cancelled = JobContext::silent();
    cancelled.cancel();
    let mut events = Vec::new();
    assert!(
        job.run(&cancelled, &|_| Some(cancelled.clone()), &mut |e| events
            .push(e))
            .is_err()
    );
}

#[test]
fn kernels_on_a_session_measures_what_is_missing_and_records_it() {
    let dir = tempfile::tempdir().unwrap();
    small_demo(dir.path());
    let run = || {
        std::process::Command::new(env!("CARGO_BIN_EXE_lensblur"))
            .args(["kernels", "--session"])
            .arg(dir.path())
            .output()
            .unwrap()
    };
    let out = run();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("4 shots measured, 0 from the cache"), "{err}");
    assert!(err.contains("4 of 4 shots have kernels"), "{err}");
    // Each shot's status is in the session file the studio opens.
    let s = Session::open(dir.path()).unwrap();
    assert!(
        s.shots
            .iter()
            .all(|x| x.detect.is_done() && x.kernels.is_done())
    );
    let out = run();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("0 shots measured, 4 from the cache"), "{err}");
}

#[test]
fn a_survey_that_ends_after_a_job_keeps_what_the_job_recorded() {
    let dir = tempfile::tempdir().unwrap();
    small_demo(dir.path());
    let (mut project, _) = Project::open(dir.path(), "the test").unwrap();
    let ctx = JobContext::silent();

    // The survey reads an empty cache, and a detection job records every shot before
    // the survey's result is taken (the studio surveys on a job at open, while the
    // user may already have pressed Detect).
    let stale = project.survey_job().run(&ctx).unwrap();
    run(&mut project, &MeasurePlan::missing(Stages::Detect));
    assert!(project.apply_survey(stale).is_empty());
    assert!(
        project
            .shots()
            .all(|s| s.shot.detect.is_done() && s.state.detection.is_some()),
        "the survey read before the job must not undo what it recorded"
    );

    // A survey that found those detections, taken after the chart changed: they are
    // not the new chart's.
    let found = project.survey_job().run(&ctx).unwrap();
    let mut chart = project.session().chart.clone();
    chart.square_mm *= 2.0;
    project.session_mut().chart = chart;
    project.forget_results(true, true);
    project.apply_survey(found);
    assert!(
        project
            .shots()
            .all(|s| s.state.detection.is_none() && s.shot.detect == StageStatus::Pending),
        "a survey of another chart's results is not taken"
    );
}
