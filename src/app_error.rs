//! What only this crate can fail at (the GPU, the display, the figures), not the GPU-free core.
//! These errors travel in the core's [`Error::External`], so the core's traits
//! (`flight::frame::Presenter`) carry them and the binary prints them as one line.

use std::path::PathBuf;

use crate::error::Error;

/// The renderer's, the window's and the figures' errors.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AppError {
    /// No usable GPU, or the GPU refused a request (creation, limits, readback).
    #[error("GPU: {0}")]
    Gpu(String),
    /// No window can be opened here (no display); the message says how to fly headless.
    #[error("{0}")]
    NoDisplay(String),
    /// A figure that cannot be drawn: nothing to plot, an unusable value, or a drawing failure.
    #[error("{}: cannot draw the figure: {problem}", path.display())]
    Plot { path: PathBuf, problem: String },
}

impl From<AppError> for Error {
    fn from(e: AppError) -> Error {
        Error::External(Box::new(e))
    }
}

impl AppError {
    /// The app error inside `e`, if it holds one.
    pub fn of(e: &Error) -> Option<&AppError> {
        match e {
            Error::External(inner) => inner.downcast_ref(),
            _ => None,
        }
    }
}

/// A GPU error ([`AppError::Gpu`]) as the library's error.
pub fn gpu(problem: impl Into<String>) -> Error {
    AppError::Gpu(problem.into()).into()
}

/// A figure that cannot be drawn ([`AppError::Plot`]).
pub fn plot(path: impl Into<PathBuf>, problem: impl Into<String>) -> Error {
    AppError::Plot { path: path.into(), problem: problem.into() }.into()
}
