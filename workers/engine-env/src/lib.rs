//! Where the Python engines (`workers/engines`, the `vint_engines` package) and the interpreter
//! that runs them are: the two things a process needs before it can start an engine.
//!
//! `vint-worker` starts engines to run tasks and `vintctl study` starts one to measure it; both
//! take flags or `VINT_PYTHON` / `VINT_ENGINES_DIR`, and fall back to the source checkout they were
//! built from. This crate is that fallback, in one place, so that neither binary depends on the
//! other's crate to find it. It is not `vint-core`: core is pure, and these are paths on the
//! machine that built the binary. It knows nothing about the engine protocol (`vint-runtime`).

use std::path::PathBuf;

/// The engines' package directory (put on `PYTHONPATH`) and their Python interpreter.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EngineEnv {
    pub engines_dir: PathBuf,
    pub python: PathBuf,
}

impl EngineEnv {
    /// The source checkout this binary was built from: `workers/engines` and `.venv/bin/python`
    /// at the repository root (what `scripts/setup.sh` creates).
    pub fn checkout() -> EngineEnv {
        let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
        EngineEnv { engines_dir: here.join("../engines"), python: here.join("../../.venv/bin/python") }
    }

    /// `VINT_ENGINES_DIR` and `VINT_PYTHON` where set, the checkout's otherwise.
    pub fn from_env() -> EngineEnv {
        let checkout = EngineEnv::checkout();
        let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
        EngineEnv {
            engines_dir: var("VINT_ENGINES_DIR").unwrap_or(checkout.engines_dir),
            python: var("VINT_PYTHON").unwrap_or(checkout.python),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checkout_holds_the_engines_package() {
        let env = EngineEnv::checkout();
        assert!(env.engines_dir.join("vint_engines/__init__.py").is_file(), "{}", env.engines_dir.display());
        assert!(env.python.ends_with(".venv/bin/python"));
    }
}
