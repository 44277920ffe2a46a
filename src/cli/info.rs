//! `lensblur info FILE [--json]`: what lensblur reads from a shot or photo (the image it
//! measures, CFA, levels, camera, lens, settings, focus distance, the decoder), the
//! pixels decoded so a file without a picture is refused. The JSON is in
//! docs/formats.md.

use anyhow::Result;
use lensblur::raw::{FileInfo, FocusDistance, inspect};
use std::path::PathBuf;

#[derive(clap::Args, Default)]
pub struct Args {
    /// A RAW file, or a PNG/TIFF/JPEG image.
    pub file: PathBuf,
    /// Print the JSON form (docs/formats.md) instead of lines for people.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let info = inspect(&args.file)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print!("{}", text(&info));
    }
    Ok(())
}

fn text(i: &FileInfo) -> String {
    let unknown = || "not recorded".to_string();
    let or_unknown = |s: &Option<String>| s.clone().unwrap_or_else(unknown);
    let number = |v: Option<f64>, unit: &str| v.map_or_else(unknown, |v| format!("{v}{unit}"));
    let levels = match (&i.cfa, i.black, i.white) {
        (Some(cfa), Some(b), Some(w)) => format!(
            "CFA {cfa}, black {} {} {} {}, white {w}",
            b[0], b[1], b[2], b[3]
        ),
        _ => "no CFA (RGB or grey data, 0–1 linear)".to_string(),
    };
    let focus = match i.focus_distance_m {
        Some(FocusDistance::Metres(m)) => format!("{m} m"),
        Some(FocusDistance::Infinity(_)) => "infinity".to_string(),
        None => unknown(),
    };
    format!(
        "file:      {}\ndecoder:   {}\nimage:     {} × {} px\nlevels:    {levels}\ncamera:    {} {}\nlens:      {}\nfocal:     {}\naperture:  {}\nfocus at:  {focus}\n",
        i.file,
        i.decoder.name(),
        i.width,
        i.height,
        or_unknown(&i.make),
        or_unknown(&i.model),
        or_unknown(&i.lens),
        number(i.focal_length_mm, " mm"),
        i.f_number.map_or_else(unknown, |f| format!("f/{f}")),
    )
}
