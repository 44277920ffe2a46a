//! `lensblur simulate` (being built).

#[derive(clap::Args, Default)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("'simulate' is not built yet")
}
