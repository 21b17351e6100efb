use std::path::PathBuf;

/// An I/O or format problem, always tied to the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The OS error is part of the message and deliberately not a `source()`: error chains
    /// (`{:#}`) would print it twice.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: not a readable EXR file: {message}")]
    Exr { path: PathBuf, message: String },
    #[error("{path}: not a readable image: {message}")]
    Image { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            error,
        }
    }

    /// The OS error's kind, for an I/O error.
    pub fn io_kind(&self) -> Option<std::io::ErrorKind> {
        match self {
            Error::Io { error, .. } => Some(error.kind()),
            _ => None,
        }
    }
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// What is wrong with a JSON document, where, without quoting it: `serde_json`'s messages for a
/// value of the wrong type quote the value, and a file that is not what it claims to be (a
/// shard index that is really some other file) must not have its bytes echoed. Syntax errors
/// and missing fields name only the grammar and our own field names, so they are kept.
pub fn json_problem(e: &serde_json::Error) -> String {
    use serde_json::error::Category;
    let at = format!("line {} column {}", e.line(), e.column());
    match e.classify() {
        Category::Io => format!("read error at {at}"),
        Category::Eof => format!("ends too early, at {at}"),
        Category::Syntax => {
            let text = e.to_string();
            let what = text.split(" at line ").next().unwrap_or("syntax error");
            format!("not JSON: {what} at {at}")
        }
        Category::Data => {
            let text = e.to_string();
            match text.strip_prefix("missing field ") {
                Some(rest) => format!(
                    "missing field {}",
                    rest.split(" at line ").next().unwrap_or(rest)
                ),
                None => format!("a value of the wrong type or out of range at {at}"),
            }
        }
    }
}
