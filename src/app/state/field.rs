//! The Kernel field view's colouring choices: its colour range and difference map.

/// How the Kernel field view colours its squares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColourRange {
    /// From the smallest to the largest value shown (over every panel, so compared
    /// fields share one scale).
    Data,
    /// A range the user set (σ, px), kept across shots and settings so that fields
    /// compare by eye.
    Fixed { min: f64, max: f64 },
}

/// The difference maps of the Kernel field view: σ(A) − σ(B) at each square.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Difference {
    /// The selected shot's measured Gaussians − the profile's prediction there, at the
    /// shot's setting.
    MeasuredMinusPredicted,
    /// Unit A − unit B: the profile − the second profile loaded, else the demo lens −
    /// its second unit, at the sliders' setting.
    UnitAMinusB,
    /// Channel R − channel B of the source shown (lateral colour, in blur).
    RedMinusBlue,
}

/// The Kernel field view's colouring choices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldOptions {
    pub range: ColourRange,
    /// A difference map instead of the fields, or `None`.
    pub difference: Option<Difference>,
}

impl Default for FieldOptions {
    fn default() -> Self {
        Self {
            range: ColourRange::Data,
            difference: None,
        }
    }
}
