//! The worker runtime: everything between the coordinator and the engines.
//!
//! `worker` leases tasks and reports their results; `engine` hosts the long-lived Python engines
//! (MuJoCo grasp, Blender render, OpenCV noise) behind the framed protocol of
//! `workers/engines/PROTOCOL.md`; `package` is the one stage written in Rust. The runtime moves
//! artifacts between object storage and engines; it never decides what a task means — the
//! planner in `vint-core` does, through the coordinator.

pub mod engine;
pub mod package;
pub mod worker;

use std::path::PathBuf;

/// Default engines directory and Python interpreter of a source checkout: `workers/engines` and
/// `.venv/bin/python` at the repository root (overridable by flags or `VINT_ENGINES_DIR` /
/// `VINT_PYTHON`).
pub fn checkout_defaults() -> (PathBuf, PathBuf) {
    let runtime = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let engines = runtime.join("../engines");
    let python = runtime.join("../../.venv/bin/python");
    (engines, python)
}
