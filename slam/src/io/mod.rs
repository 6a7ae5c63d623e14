//! Reading and writing what the sensor side needs: RGB-D datasets (TUM, ICL-NUIM, plain folders),
//! images, trajectories and meshes. Every error names the file and, where there is one, the line or
//! frame; every write goes through a temporary file renamed into place.

pub mod deepdeform;
pub mod flow;
pub mod folder;
pub mod iclnuim;
pub mod images;
pub mod meshes;
pub mod ply;
pub mod sequence;
pub mod trajectory;
pub mod tum;

use dynamap_residuals::text::without_bom;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// A file that could not be read or written, with the place of the fault.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{}{}: {message}", path.display(), if *line > 0 { format!(":{line}") } else { String::new() })]
pub struct IoError {
    /// The file.
    pub path: PathBuf,
    /// 1-based line (0 for the file as a whole).
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

impl IoError {
    /// An error about a whole file.
    pub fn file(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self {
            path: path.as_ref().to_path_buf(),
            line: 0,
            message: message.into(),
        }
    }
    /// The same error, its message prefixed with the frame it concerns.
    pub(crate) fn in_frame(self, frame: usize) -> Self {
        Self {
            message: format!("frame {frame}: {}", self.message),
            ..self
        }
    }
    /// The error for asking a sequence of `len` frames (at `root`) for frame `frame`.
    pub(crate) fn no_frame(root: impl AsRef<Path>, frame: usize, len: usize) -> Self {
        Self::file(root, format!("frame {frame} does not exist ({len} frames)"))
    }
    /// An error at a line.
    pub fn line(path: impl AsRef<Path>, line: usize, message: impl Into<String>) -> Self {
        Self {
            path: path.as_ref().to_path_buf(),
            line,
            message: message.into(),
        }
    }
}

/// Reads a text file, naming it in the error; a leading byte-order mark is dropped
/// (`dynamap_residuals::text`).
pub(crate) fn read_text(path: impl AsRef<Path>) -> Result<String, IoError> {
    let path = path.as_ref();
    let mut text = std::fs::read_to_string(path)
        .map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
    let mark = text.len() - without_bom(&text).len();
    text.drain(..mark);
    Ok(text)
}

/// Writes `bytes` to `path` through a temporary file in the same folder, renamed into place: a
/// failure leaves any previous file intact and no partial one.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<(), IoError> {
    let path = path.as_ref();
    dynamap_residuals::atomic::write(path, bytes)
        .map_err(|e| IoError::file(path, format!("cannot write: {e}")))
}

/// Splits a text into (line number, fields) for its non-empty, non-comment lines.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then(|| (i + 1, l.split_whitespace().collect()))
    })
}

/// Parses field `k` of a line as f64, naming the field in the error.
pub(crate) fn number(
    path: &Path,
    line: usize,
    fields: &[&str],
    k: usize,
    name: &str,
) -> Result<f64, IoError> {
    let tok = fields
        .get(k)
        .ok_or_else(|| IoError::line(path, line, format!("missing field {name}")))?;
    let v: f64 = tok
        .parse()
        .map_err(|_| IoError::line(path, line, format!("field {name}: '{tok}' is not a number")))?;
    if !v.is_finite() {
        return Err(IoError::line(
            path,
            line,
            format!("field {name}: '{tok}' is not finite"),
        ));
    }
    Ok(v)
}
