//! vint's domain vocabulary: the dataset spec and its validation, stages, the task state machine,
//! seed derivation, sample identities and the planner that turns a spec into tasks.
//!
//! Everything here is pure: no I/O, no clocks, no randomness. The store, the coordinator and the
//! workers build on these types; none of them redefines what lives here.

pub mod asset;
pub mod budget;
pub mod catalog;
pub mod contract;
pub mod cost;
pub mod limits;
pub mod plan;
pub mod reuse;
pub mod sample;
pub mod seed;
pub mod spec;
pub mod split;
pub mod stage;
pub mod state;
pub mod suggest;

pub use sample::{GraspId, SampleId};
pub use spec::{DatasetSpec, SpecError, SpecErrors};
pub use stage::Stage;
pub use state::{AttemptOutcome, JobState, TaskState};
