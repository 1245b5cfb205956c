//! Where a command that reads a job's records finds them: the state directory of `vintctl run`
//! (`vint.db`, `objects/`), or a cluster's database and object store by URL.

use std::path::Path;

use anyhow::{Context, anyhow};

use crate::{Failure, bad_input};

/// The database URL and the object store URL of the (absolute) state directory `state`: where
/// `vintctl run` keeps a job's records and where the commands that read them look.
pub fn state_urls(state: &Path) -> (String, String) {
    (format!("sqlite://{}", state.join("vint.db").display()), format!("file://{}", state.join("objects").display()))
}

pub enum Records<'a> {
    /// A `vintctl run` state directory.
    State(&'a Path),
    /// A database URL and an object store URL (`--database`, `--store`).
    Urls { database: &'a str, store: &'a str },
}

impl Records<'_> {
    /// The database URL and the object store URL; a state directory must hold a database.
    pub fn urls(&self) -> Result<(String, String), Failure> {
        match self {
            Records::State(state) => {
                let db = state.join("vint.db");
                if !db.is_file() {
                    return Err(bad_input(anyhow!(
                        "--state: {} holds no vint.db (the state directory of `vintctl run`)",
                        state.display()
                    )));
                }
                let state = state.canonicalize().with_context(|| format!("resolving {}", state.display()))?;
                Ok(state_urls(&state))
            }
            Records::Urls { database, store } => Ok((database.to_string(), store.to_string())),
        }
    }
}
