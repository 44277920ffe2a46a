//! The square inspector's key and what its job hands back, and the `Arc` identity that
//! cache keys hold.

use crate::detect::Detection;
use crate::detect::inspect::SquareInspection;
use crate::plane::Channel;
use crate::review::SquareFacts;
use crate::session::ShotId;
use std::sync::Arc;

/// An `Arc`'s identity as part of a cache key. The key holds the `Arc`, so the value
/// stays alive and an equal pointer always means the same value.
pub struct Same<T>(pub(crate) Option<Arc<T>>);

impl<T> Same<T> {
    pub(crate) fn of(v: Option<&Arc<T>>) -> Self {
        Self(v.cloned())
    }
}

impl<T> Clone for Same<T> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<T> PartialEq for Same<T> {
    fn eq(&self, other: &Self) -> bool {
        match (&self.0, &other.0) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        }
    }
}

impl<T> std::fmt::Debug for Same<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            Some(a) => write!(f, "Same({:p})", Arc::as_ptr(a)),
            None => write!(f, "Same(none)"),
        }
    }
}

/// Which square's inspection, of what: results for another key are stale.
#[derive(Clone, Debug, PartialEq)]
pub struct InspectKey {
    pub session: u64,
    pub shot: ShotId,
    pub square: (usize, usize),
    pub channel: Channel,
    pub(crate) detection: Same<Detection>,
}

/// What an inspection job hands back: the crops, the square's numbers and the crops'
/// grey images (textures are made from them on the UI thread).
pub struct InspectedSquare {
    pub crops: SquareInspection,
    pub facts: Option<SquareFacts>,
    pub images: [egui::ColorImage; 3],
}
