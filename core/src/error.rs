//! The library's error type. Every variant names the file, field or value at fault so a user can act on it.

use std::path::PathBuf;

/// Errors returned by the spinedrr library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its content is not what the format requires.
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    /// A parameter (CLI flag, config key, JSON field) has a value that cannot be used.
    #[error("invalid {field}: {message}")]
    Invalid { field: String, message: String },
    /// A numerical procedure could not produce a result (degenerate input, singular system).
    #[error("{0}")]
    Numerical(String),
    /// Serialising or encoding a product (config, unit file, table, image) failed.
    #[error("encoding {what}: {message}")]
    Encode { what: String, message: String },
    /// The running system refused a resource (a thread pool, a thread).
    #[error("{0}")]
    Resource(String),
    /// A broken invariant inside spinedrr: a bug, not a problem with the user's input.
    #[error("internal error (a bug in spinedrr; please report it): {0}")]
    Internal(String),
    /// An external library (Embree, OpenCV) reported an error.
    #[error("{library}: {message}")]
    External {
        library: &'static str,
        message: String,
    },
}

/// Shorthand result type of the library.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// An [`Error::Invalid`] for `field` with a message.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// An [`Error::Format`] for `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// An [`Error::Encode`] for `what`.
    pub fn encode(what: impl Into<String>, message: impl std::fmt::Display) -> Self {
        Error::Encode {
            what: what.into(),
            message: message.to_string(),
        }
    }

    /// An [`Error::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

impl Error {
    /// An [`Error::External`] of OpenCV (the text of the exception it threw).
    pub(crate) fn opencv(message: String) -> Self {
        Error::External {
            library: "OpenCV",
            message,
        }
    }
}

/// A number as a message shows it: plainly between 10⁻³ and 10⁶ (and 0), in scientific notation beyond,
/// so that an absurd value reads `1e308`, not three hundred digits.
pub fn shown(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-3..1e6).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod shown_tests {
    #[test]
    fn huge_and_tiny_values_read_in_scientific_notation() {
        assert_eq!(super::shown(1e308), "1e308");
        assert_eq!(super::shown(-2.5e-7), "-2.5e-7");
        assert_eq!(super::shown(12345.5), "12345.5");
        assert_eq!(super::shown(0.0), "0");
        assert_eq!(super::shown(f64::NAN), "NaN");
    }
}
