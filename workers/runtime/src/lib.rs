//! The worker runtime: everything between the coordinator and the engines.
//!
//! `worker` leases tasks and reports their results; `engine` hosts the long-lived Python engines
//! (MuJoCo grasp, Blender render, OpenCV noise) behind the framed protocol of
//! `workers/engines/PROTOCOL.md`; `package` is the one stage written in Rust. The runtime moves
//! artifacts between object storage and engines; it never decides what a task means — the
//! planner in `vint-core` does, through the coordinator. `timing_only` is the measuring mode that
//! runs no engine (`--engine-mode timing-only`, never the default). `metrics` is what a worker
//! reports at `/metrics` and `/healthz` (`--metrics-listen`).

pub mod engine;
pub mod metrics;
pub mod package;
pub mod timing_only;
pub mod worker;
