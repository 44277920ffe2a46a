//! What every view may read, borrowed for one frame: the project (the session and the
//! results made of it) and the shots as the window has them loaded. The app's own
//! accessors read through it too, so each result is found one way.

use super::{ShotPreview, ShotView};
use crate::crossval::CvReport;
use crate::detect::Detection;
use crate::kernel::file::KernelsFile;
use crate::model::Dataset;
use crate::profile::Profile;
use crate::project::Project;
use crate::session::{Session, ShotId};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The project and the loaded shots, read-only: views change them only by commands.
#[derive(Clone, Copy)]
pub struct ViewerContext<'a> {
    pub project: Option<&'a Project>,
    pub shots: &'a BTreeMap<ShotId, ShotView>,
}

impl<'a> ViewerContext<'a> {
    /// The open session.
    #[must_use]
    pub fn session(self) -> Option<&'a Session> {
        self.project.map(Project::session)
    }

    /// Whether the open session is the demo's (its lens's truth can be shown).
    #[must_use]
    pub fn is_demo(self) -> bool {
        self.session().is_some_and(|s| s.is_demo)
    }

    /// The session's measured Gaussians over every shot with kernels and a setting.
    #[must_use]
    pub fn dataset(self) -> Option<&'a Arc<Dataset>> {
        self.project?.dataset()
    }

    /// The lens profile in use (calibrated here or loaded) and where it lies.
    #[must_use]
    pub fn profile(self) -> Option<&'a (PathBuf, Arc<Profile>)> {
        self.project?.profile()
    }

    /// A second profile shown beside the first (another unit of the lens).
    #[must_use]
    pub fn compare_profile(self) -> Option<&'a (PathBuf, Arc<Profile>)> {
        self.project?.compare_profile()
    }

    /// The cross-validation report of the profile's fit.
    #[must_use]
    pub fn cv(self) -> Option<&'a Arc<CvReport>> {
        self.project?.cv()
    }

    /// The shot's detection, this run's or read back from the session's results.
    #[must_use]
    pub fn detection(self, id: ShotId) -> Option<&'a Arc<Detection>> {
        self.project?.detection(id)
    }

    /// The shot's measured kernels and their Gaussians (all channels).
    #[must_use]
    pub fn kernels(self, id: ShotId) -> Option<&'a Arc<KernelsFile>> {
        self.project?.kernels(id)
    }

    /// The shot as the window has it: loading, loaded or unreadable.
    #[must_use]
    pub fn shot(self, id: ShotId) -> Option<&'a ShotView> {
        self.shots.get(&id)
    }

    /// The shot loaded for display, once it is.
    #[must_use]
    pub fn preview(self, id: ShotId) -> Option<&'a ShotPreview> {
        self.shots.get(&id).and_then(ShotView::preview)
    }

    /// Why the shot cannot be read, if it cannot.
    #[must_use]
    pub fn unreadable(self, id: ShotId) -> Option<&'a str> {
        self.shots.get(&id).and_then(ShotView::unreadable)
    }

    /// A path as the UI shows it: relative to the session folder when it lies inside,
    /// `~/…` under the home folder, absolute otherwise. Where the session lives is one
    /// hover away (the session name's tooltip); repeating it in every line would crowd
    /// the window and tie what it shows to where the folder happens to be.
    #[must_use]
    pub fn shown_path(self, path: &Path) -> String {
        if let Some(s) = self.session()
            && let Ok(rel) = path.strip_prefix(s.folder())
            && !rel.as_os_str().is_empty()
        {
            return rel.display().to_string();
        }
        if let Some(home) = std::env::var_os("HOME").map(PathBuf::from)
            && let Ok(rel) = path.strip_prefix(&home)
        {
            return format!("~/{}", rel.display());
        }
        path.display().to_string()
    }
}
