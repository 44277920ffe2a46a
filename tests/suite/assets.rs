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
        asset("chart_24x16_20mm.pdf") == to_pdf(&spec, None).expect("pdf"),
        "assets/chart_24x16_20mm.pdf is not what `lensblur chart` writes"
    );
}

/// The charts for A4, A3 and A2 are the default chart with its squares sized to each
/// sheet (`lensblur chart --paper a4 --out assets/chart_a4.pdf --spec-out
/// assets/chart_a4.json`, and so on).
#[test]
fn the_sheet_charts_are_the_default_chart_sized_to_their_paper() {
    for paper in ["a4", "a3", "a2"] {
        let want = ChartSpec::default();
        let spec: ChartSpec =
            serde_json::from_slice(&asset(&format!("chart_{paper}.json"))).expect("spec");
        let sized = ChartSpec {
            square_mm: want.square_to_fill(paper.parse().expect("a paper")),
            ..want
        };
        assert_eq!(spec, sized, "{paper}");
        assert!(
            asset(&format!("chart_{paper}.pdf"))
                == to_pdf(&spec, Some(paper.parse().expect("a paper"))).expect("pdf"),
            "assets/chart_{paper}.pdf is not what `lensblur chart --paper {paper}` writes"
        );
    }
}
