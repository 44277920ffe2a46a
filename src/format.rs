//! Versions of the files lensblur writes (docs/formats.md, "Versions").
//!
//! Every JSON file carries `"schema": "lensblur.<kind>/<version>"`. A reader takes its
//! own version and every earlier one (migrating the older ones in its own module, as
//! darktable does with its parameter versions), and refuses a newer version with both
//! numbers, so an old lensblur never half-reads a file a newer one wrote. The rule lives
//! here, once; each format's module says which versions it knows.

/// One format's kind and the version this build writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Schema {
    /// `session`, `kernels`, ... as in `lensblur.session/2`.
    pub kind: &'static str,
    /// The version this build writes; every earlier one is read.
    pub current: u32,
    /// The version a file without a `schema` field is (files written before the field
    /// existed, or by hand); `None` where the field was always written.
    pub unversioned: Option<u32>,
}

/// Why a file's schema is not one this build reads.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum VersionError {
    #[error(
        "lensblur.{kind} version {found} is newer than this lensblur reads (up to version {current}): update lensblur"
    )]
    Newer {
        kind: &'static str,
        found: u32,
        current: u32,
    },
    #[error(
        "schema '{found}' is not a lensblur.{kind} file (expected 'lensblur.{kind}/1' to '/{current}')"
    )]
    Foreign {
        kind: &'static str,
        found: String,
        current: u32,
    },
    #[error("no schema field: not a lensblur.{kind} file")]
    Missing { kind: &'static str },
}

impl Schema {
    /// The schema string this build writes.
    #[must_use]
    pub fn tag(&self) -> String {
        format!("lensblur.{}/{}", self.kind, self.current)
    }

    /// The version of a file whose `schema` field reads `found` (absent or empty: the
    /// unversioned form).
    ///
    /// # Errors
    /// A newer version, another kind of file, or no schema where one is required.
    pub fn version_of(&self, found: Option<&str>) -> Result<u32, VersionError> {
        let found = found.filter(|s| !s.is_empty());
        let Some(found) = found else {
            return self
                .unversioned
                .ok_or(VersionError::Missing { kind: self.kind });
        };
        let foreign = || VersionError::Foreign {
            kind: self.kind,
            found: found.chars().take(80).collect(),
            current: self.current,
        };
        let version = found
            .strip_prefix("lensblur.")
            .and_then(|rest| rest.strip_prefix(self.kind))
            .and_then(|rest| rest.strip_prefix('/'))
            .and_then(|v| v.parse::<u32>().ok())
            .filter(|&v| v >= 1)
            .ok_or_else(foreign)?;
        if version > self.current {
            return Err(VersionError::Newer {
                kind: self.kind,
                found: version,
                current: self.current,
            });
        }
        Ok(version)
    }

    /// The `schema` field of a JSON text, read before the rest so that a newer file is
    /// refused for its version rather than for a field this build does not know.
    ///
    /// # Errors
    /// As [`Schema::version_of`]; text that is not a JSON object reads as unversioned.
    pub fn version_of_json(&self, text: &str) -> Result<u32, VersionError> {
        #[derive(serde::Deserialize)]
        struct Head {
            #[serde(default)]
            schema: Option<serde_json::Value>,
        }
        let head: Option<Head> = serde_json::from_str(text).ok();
        match head.and_then(|h| h.schema) {
            None => self.version_of(None),
            Some(serde_json::Value::String(s)) => self.version_of(Some(&s)),
            Some(other) => self.version_of(Some(&other.to_string())),
        }
    }
}

/// A value written with its schema in front (`{"schema": ..., ...its fields}`), for
/// the files lensblur writes and only people and scripts read (reports, predictions,
/// the simulator's truth).
#[derive(serde::Serialize)]
pub struct Versioned<'a, T: serde::Serialize> {
    schema: String,
    #[serde(flatten)]
    value: &'a T,
}

impl<'a, T: serde::Serialize> Versioned<'a, T> {
    #[must_use]
    pub fn new(schema: &Schema, value: &'a T) -> Self {
        Self {
            schema: schema.tag(),
            value,
        }
    }
}

/// An output-only format at its first version: written with [`Versioned`], never read
/// back by lensblur.
const fn output_only(kind: &'static str) -> Schema {
    Schema {
        kind,
        current: 1,
        unversioned: None,
    }
}

/// Output-only formats: written with [`Versioned`], never read back by lensblur.
pub const PREDICTION: Schema = output_only("prediction");
pub const EXPERIMENT: Schema = output_only("experiment");
pub const LENS: Schema = output_only("lens");
pub const TRUTH: Schema = output_only("truth");

#[cfg(test)]
mod tests {
    use super::*;

    const S: Schema = Schema {
        kind: "thing",
        current: 3,
        unversioned: Some(1),
    };

    #[test]
    fn versions_up_to_the_current_one_are_read_and_newer_refused_with_both_numbers() {
        assert_eq!(S.tag(), "lensblur.thing/3");
        assert_eq!(S.version_of(Some("lensblur.thing/2")), Ok(2));
        assert_eq!(S.version_of(Some("lensblur.thing/3")), Ok(3));
        assert_eq!(S.version_of(None), Ok(1));
        assert_eq!(S.version_of(Some("")), Ok(1));
        let e = S
            .version_of(Some("lensblur.thing/4"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains('4') && e.contains('3') && e.contains("newer"),
            "{e}"
        );
        for bad in [
            "lensblur.other/1",
            "lensblur.thing/0",
            "lensblur.thing/x",
            "thing/1",
        ] {
            assert!(
                matches!(S.version_of(Some(bad)), Err(VersionError::Foreign { .. })),
                "{bad}"
            );
        }
        let strict = Schema {
            unversioned: None,
            ..S
        };
        assert!(matches!(
            strict.version_of(None),
            Err(VersionError::Missing { .. })
        ));
    }

    #[test]
    fn the_schema_is_read_before_the_rest() {
        assert_eq!(
            S.version_of_json(r#"{"schema":"lensblur.thing/2","x":[1,2"#)
                .unwrap_or(0),
            1,
            "malformed JSON reads as unversioned; its parse error comes later"
        );
        assert_eq!(
            S.version_of_json(r#"{"future_field":{}, "schema":"lensblur.thing/2"}"#),
            Ok(2)
        );
        assert!(
            S.version_of_json(r#"{"schema":"lensblur.thing/9"}"#)
                .is_err()
        );
        assert!(S.version_of_json(r#"{"schema":7}"#).is_err());
    }
}
