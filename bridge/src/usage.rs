//! An error in what the user asked for: bass-bridge exits with status 2 for it, like clap
//! for a bad option (every module that checks an option's value returns it).

/// An error in what the user asked for (exit status 2, like a bad option).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);
