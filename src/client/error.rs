//! [`ClientError`]: why a sync did not install a bundle, and whether retrying can help.

use std::path::{Path, PathBuf};

use eyekey_core::bundle::BundleError;
use uuid::Uuid;

/// Why a sync did not install a bundle. [`ClientError::is_retryable`] tells a passing problem (the server is
/// away, a download broke) from one that needs a person (a wrong token or URL, an unwritable directory).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The configuration is unusable.
    #[error("{0}")]
    Config(String),
    /// No connection, a timeout, or a connection that broke off.
    #[error("cannot reach the eyekey server at {url}: {reason}")]
    Unreachable {
        /// The request's URL.
        url: String,
        /// The transport error and its causes.
        reason: String,
    },
    /// 401: the server does not know the token.
    #[error(
        "the server refused the display token (401 Unauthorized): check --token or EYEKEY_DISPLAY_TOKEN; \
         rotating the display's token replaces the old one"
    )]
    Unauthorised,
    /// 404 from an endpoint every eyekey server has: the URL does not point at one.
    #[error("{url} answered 404 Not Found: is --server the base URL of an eyekey service?")]
    NoApi {
        /// The request's URL.
        url: String,
    },
    /// 404 for a job that was listed a moment ago.
    #[error("job {job} is no longer offered to this display (404)")]
    JobGone {
        /// The job.
        job: Uuid,
    },
    /// Any other unexpected status.
    #[error("{url} answered {status}: {message}")]
    Status {
        /// The request's URL.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// The server's error message, or the start of its body.
        message: String,
    },
    /// An answer that is not what the API documents.
    #[error("unexpected answer from {url}: {reason}")]
    Protocol {
        /// The request's URL.
        url: String,
        /// What is wrong.
        reason: String,
    },
    /// The downloaded bundle failed verification.
    #[error("the bundle of job {job} failed verification")]
    Bundle {
        /// The job.
        job: Uuid,
        /// What the reader found.
        #[source]
        source: BundleError,
    },
    /// The downloaded bundle does not match what the server listed, or is too large.
    #[error("the bundle of job {job} does not match the server's listing: {reason}")]
    Mismatch {
        /// The job.
        job: Uuid,
        /// What differs.
        reason: String,
    },
    /// The preview could not be simulated.
    #[error("cannot simulate the preview: {0}")]
    Preview(String),
    /// A file operation in the output directory failed.
    #[error("cannot {op} {}", path.display())]
    Io {
        /// What was being done.
        op: &'static str,
        /// The path.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

impl ClientError {
    /// True when trying again later may succeed without anybody changing anything.
    pub fn is_retryable(&self) -> bool {
        match self {
            Self::Unreachable { .. }
            | Self::JobGone { .. }
            | Self::Protocol { .. }
            | Self::Bundle { .. }
            | Self::Mismatch { .. } => true,
            Self::Status { status, .. } => *status >= 500 || *status == 408 || *status == 429,
            Self::Config(_) | Self::Unauthorised | Self::NoApi { .. } | Self::Preview(_) | Self::Io { .. } => false,
        }
    }
}

pub(super) fn io_err<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> ClientError + 'a {
    move |source| ClientError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

/// The error and its causes on one line (reqwest's own message rarely names the cause).
pub(super) fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let part = s.to_string();
        if !text.contains(&part) {
            text.push_str(": ");
            text.push_str(&part);
        }
        source = s.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_problems_of_the_moment_are_retried() {
        let url = String::from("http://x");
        assert!(ClientError::Unreachable {
            url: url.clone(),
            reason: String::new()
        }
        .is_retryable());
        assert!(ClientError::Status {
            url: url.clone(),
            status: 503,
            message: String::new()
        }
        .is_retryable());
        assert!(!ClientError::Status {
            url: url.clone(),
            status: 400,
            message: String::new()
        }
        .is_retryable());
        assert!(!ClientError::Unauthorised.is_retryable());
        assert!(!ClientError::NoApi { url }.is_retryable());
    }
}
