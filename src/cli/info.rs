//! `lensblur info FILE [--json]`: what lensblur reads from a shot or photo (the image it
//! measures, CFA, levels, camera, lens, settings, focus distance, the decoder), the
//! pixels decoded so a file without a picture is refused. The JSON is in
//! docs/formats.md.

use anyhow::Result;
use lensblur::plane::{f_number_text, focal_text};
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
        "file:      {}\ndecoder:   {}\nimage:     {} × {} px\nlevels:    {levels}\ncamera:    {}\nlens:      {}\nfocal:     {}\naperture:  {}\nfocus at:  {focus}\n",
        i.file,
        i.decoder.name(),
        i.width,
        i.height,
        camera_name(i.make.as_deref(), i.model.as_deref()).unwrap_or_else(unknown),
        or_unknown(&i.lens),
        i.focal_length_mm.map_or_else(unknown, focal_text),
        i.f_number.map_or_else(unknown, f_number_text),
    )
}

/// The camera as people name it: "Canon EOS 6D", not the make twice where the model
/// already starts with it (as Canon and Nikon write theirs).
fn camera_name(make: Option<&str>, model: Option<&str>) -> Option<String> {
    match (make.map(str::trim), model.map(str::trim)) {
        (Some(make), Some(model)) if model.to_lowercase().starts_with(&make.to_lowercase()) => {
            Some(model.to_string())
        }
        (Some(make), Some(model)) => Some(format!("{make} {model}")),
        (Some(one), None) | (None, Some(one)) => Some(one.to_string()),
        (None, None) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::camera_name;

    #[test]
    fn a_camera_is_named_once() {
        assert_eq!(
            camera_name(Some("Canon"), Some("Canon EOS 6D")).as_deref(),
            Some("Canon EOS 6D")
        );
        assert_eq!(
            camera_name(Some("SONY"), Some("ILCE-7M3")).as_deref(),
            Some("SONY ILCE-7M3")
        );
        assert_eq!(camera_name(None, None), None);
    }
}
