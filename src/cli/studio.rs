//! `lensblur studio [SESSION]`, and `lensblur` with no arguments: the desktop studio.

use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// A session folder, its session.json, or a manifest (docs/formats.md, "Manifest"). Without one the
    /// studio opens the built-in demo session (made on first launch, then cached).
    pub session: Option<PathBuf>,
}

#[cfg(feature = "gui")]
pub fn run(args: Args) -> anyhow::Result<()> {
    let options = lensblur::app::AppOptions {
        session: args.session,
        ..Default::default()
    };
    lensblur::app::run(options).map_err(anyhow::Error::msg)
}

#[cfg(not(feature = "gui"))]
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!(
        "this lensblur was built without the studio (the 'gui' feature); use the subcommands, see --help"
    )
}
