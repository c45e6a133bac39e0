//! [`ErrorChain`]: an error and its causes on one line, for log lines and messages.
//!
//! An error's message says what failed and never repeats its cause (issue 39: no `{0}` beside
//! `#[source]`/`#[from]`); the cause is the error's [`source`](std::error::Error::source).
//! Where a library logs or prints an error, it shows the whole chain with [`error_chain`]
//! (`tracing::warn!("…: {}", error_chain(&e))`), as anyhow's `{:#}` does at binaries' edges,
//! so nothing a user needs is lost.
//!
//! ```
//! use shm_schemas::error_chain::error_chain;
//!
//! #[derive(Debug, thiserror::Error)]
//! #[error("cannot read the scene")]
//! struct ReadError(#[source] std::io::Error);
//!
//! let e = ReadError(std::io::Error::other("disk on fire"));
//! assert_eq!(error_chain(&e).to_string(), "cannot read the scene: disk on fire");
//! ```

use std::error::Error;
use std::fmt;

/// Displays an error followed by each of its causes, joined by `": "`.
#[derive(Debug, Clone, Copy)]
pub struct ErrorChain<'a>(pub &'a (dyn Error + 'static));

impl fmt::Display for ErrorChain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        let mut cause = self.0.source();
        while let Some(c) = cause {
            write!(f, ": {c}")?;
            cause = c.source();
        }
        Ok(())
    }
}

/// `e` with its causes, for a log line or a message: `"what failed: why: why deeper"`.
pub fn error_chain<'a>(e: &'a (dyn Error + 'static)) -> ErrorChain<'a> {
    ErrorChain(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("outer")]
    struct Outer(#[source] Middle);

    #[derive(Debug, thiserror::Error)]
    #[error("middle")]
    struct Middle(#[from] std::io::Error);

    #[test]
    fn every_cause_is_shown_once_in_order() {
        let e = Outer(Middle(std::io::Error::other("inner")));
        assert_eq!(error_chain(&e).to_string(), "outer: middle: inner");
        assert_eq!(
            error_chain(&std::io::Error::other("alone")).to_string(),
            "alone"
        );
    }
}
