//! The `lensblur` command: the studio (default) and the headless pipeline's subcommands
//! (ARCHITECTURE.md).

mod cli;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "lensblur",
    version,
    about = "Measure, model and remove a lens's own optical blur"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Open the studio on a session folder or manifest (the demo session without one).
    Studio(cli::studio::Args),
    /// Write the calibration chart for printing (SVG, PDF or PNG) and its spec.
    Chart(cli::chart::Args),
    /// Simulate calibration shots of a virtual lens, with a manifest and ground truth.
    Simulate(cli::simulate::Args),
    /// What lensblur reads from a shot or photo: size, CFA, levels, camera, lens,
    /// settings, focus distance and the decoder that read it.
    Info(cli::info::Args),
    /// Find the chart's squares in a shot and align each to sub-pixel accuracy.
    Detect(cli::detect::Args),
    /// Estimate the blur kernel and its Gaussian fit at every square of a shot.
    Kernels(cli::kernels::Args),
    /// Fit blur models over a calibration session and write a lens profile.
    Calibrate(cli::calibrate::Args),
    /// Cross-validate model complexity (α, β) over a calibration session.
    Crossval(cli::crossval::Args),
    /// Predict the Gaussian blur at given sensor points from a profile.
    Predict(cli::predict::Args),
    /// MTF50 over the whole frame as a map (PNG and CSV), predicted or measured.
    Sharpness(cli::sharpness::Args),
    /// Distortion, lateral colour and fall-off as a lensfun entry (XML) for darktable,
    /// RawTherapee and the other editors that correct lenses through lensfun.
    Lensfun(cli::lensfun::Args),
    /// Measured C_xx, C_yy, C_or against aperture and focal length (the paper's Fig. 4 data).
    Sweeps(cli::sweeps::Args),
    /// Remove the lens blur from a photo with a profile's or a kernels file's kernels.
    Deblur(cli::deblur::Args),
    /// Reproduce the paper's experiments.
    Experiment(cli::experiment::Args),
    /// Decode RAW files for another lensblur process (lensblur::raw::Decoding): not
    /// for people.
    #[command(name = lensblur::raw::WORKER_SUBCOMMAND, hide = true)]
    DecodeWorker,
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // A value the option does not take: one line naming the values it does.
        Err(e) if e.kind() == clap::error::ErrorKind::InvalidValue => {
            let text = e.render().to_string();
            let line: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with("For more information"))
                .collect();
            eprintln!("{}", line.join(" "));
            return ExitCode::from(2);
        }
        Err(e) => e.exit(),
    };
    // The command line and the studio decode RAW files in workers of this program, so
    // a file that crashes a decoder costs that file alone.
    lensblur::raw::set_decoding(lensblur::raw::Decoding::this_program());
    let result = match cli.command {
        None => cli::studio::run(cli::studio::Args::default()),
        Some(Command::Studio(a)) => cli::studio::run(a),
        Some(Command::Chart(a)) => cli::chart::run(a),
        Some(Command::Simulate(a)) => cli::simulate::run(a),
        Some(Command::Info(a)) => cli::info::run(a),
        Some(Command::Detect(a)) => cli::detect::run(a),
        Some(Command::Kernels(a)) => cli::kernels::run(a),
        Some(Command::Calibrate(a)) => cli::calibrate::run(a),
        Some(Command::Crossval(a)) => cli::crossval::run(a),
        Some(Command::Predict(a)) => cli::predict::run(a),
        Some(Command::Sharpness(a)) => cli::sharpness::run(a),
        Some(Command::Lensfun(a)) => cli::lensfun::run(a),
        Some(Command::Sweeps(a)) => cli::sweeps::run(a),
        Some(Command::Deblur(a)) => cli::deblur::run(a),
        Some(Command::Experiment(a)) => cli::experiment::run(a),
        Some(Command::DecodeWorker) => lensblur::raw::serve_worker().map_err(Into::into),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the outermost context first, then its causes, each once (an
            // error that names its cause, as "cannot write: {source}" does, is not
            // followed by that cause again).
            let mut line = String::new();
            for cause in e.chain().map(|c| c.to_string()) {
                if line.contains(&cause) {
                    continue;
                }
                if !line.is_empty() {
                    line.push_str(": ");
                }
                line.push_str(&cause);
            }
            eprintln!("lensblur: error: {line}");
            ExitCode::FAILURE
        }
    }
}
