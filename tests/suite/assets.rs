//! The files in `assets/` are what the code writes: the default chart's spec, and the
//! chart ready to print as SVG and PDF. A change to the chart or its export that is not
//! carried into them fails here (regenerate with `lensblur chart --out
//! assets/chart_24x16_20mm.pdf --spec-out assets/chart_24x16.json` and the `.svg`).

use lensblur::chart::ChartSpec;
use lensblur::chart::export::{to_pdf, to_svg};
use std::path::Path;

fn asset(name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets")
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn assets_are_the_default_chart() {
    let spec: ChartSpec = serde_json::from_slice(&asset("chart_24x16.json")).expect("spec");
    assert_eq!(spec, ChartSpec::default());
    let svg = to_svg(&spec).expect("svg");
    assert!(
        asset("chart_24x16_20mm.svg") == svg.as_bytes(),
        "assets/chart_24x16_20mm.svg is not what `lensblur chart` writes"
    );
    assert!(
        asset("chart_24x16_20mm.pdf") == to_pdf(&spec).expect("pdf"),
        "assets/chart_24x16_20mm.pdf is not what `lensblur chart` writes"
    );
}
