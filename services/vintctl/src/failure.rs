//! How a command fails: an error and the exit code it deserves, plus the typed errors whose
//! structure the `--json` output keeps (a spec's problems field by field, a report the command
//! had ready when it failed).
//!
//! Exit codes: 0 success, 1 failure (a job failed, a service is unreachable), 2 bad input (an
//! invalid spec, an unknown job or sample, a bad argument).

use std::fmt;
use std::path::PathBuf;

use vint_core::SpecErrors;

/// A failure and the exit code it deserves.
#[derive(Debug)]
pub struct Failure {
    pub code: u8,
    pub error: anyhow::Error,
}

impl<E: Into<anyhow::Error>> From<E> for Failure {
    fn from(e: E) -> Self {
        Failure { code: 1, error: e.into() }
    }
}

/// Bad input from the user: exit code 2.
pub fn bad_input(error: anyhow::Error) -> Failure {
    Failure { code: 2, error }
}

pub type CliResult = Result<(), Failure>;

/// A spec file with problems: every one of them, each with its field path, value and rule.
#[derive(Debug)]
pub struct InvalidSpec {
    pub file: PathBuf,
    pub errors: SpecErrors,
}

impl fmt::Display for InvalidSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.errors.0.len();
        let s = if n == 1 { "" } else { "s" };
        write!(f, "{} is not a valid spec ({n} problem{s}):\n{}", self.file.display(), self.errors)
    }
}

impl std::error::Error for InvalidSpec {}

impl InvalidSpec {
    /// Bad input: exit code 2.
    pub fn failure(file: &std::path::Path, errors: SpecErrors) -> Failure {
        bad_input(InvalidSpec { file: file.to_path_buf(), errors }.into())
    }
}

/// A failure that comes with the JSON report the command produced before it failed (the
/// dataset `run` exported from a failed job, `validate`'s verdict): with `--json` that report is
/// the output, with the error added to it, so a script reads one document either way.
#[derive(Debug)]
pub struct WithReport {
    pub report: serde_json::Value,
    pub cause: anyhow::Error,
}

impl fmt::Display for WithReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:#}", self.cause)
    }
}

impl std::error::Error for WithReport {}

impl Failure {
    /// This failure, carrying `report` for the `--json` output.
    pub fn with_report(self, report: serde_json::Value) -> Failure {
        Failure { code: self.code, error: WithReport { report, cause: self.error }.into() }
    }

    /// The report the command had ready, if any.
    pub fn report(&self) -> Option<&serde_json::Value> {
        self.error.downcast_ref::<WithReport>().map(|w| &w.report)
    }

    /// The spec problems behind this failure, if it is an invalid spec.
    pub fn spec_errors(&self) -> Option<&SpecErrors> {
        let cause = self.error.downcast_ref::<WithReport>().map_or(&self.error, |w| &w.cause);
        cause.downcast_ref::<InvalidSpec>().map(|e| &e.errors)
    }
}
