//! The command-line flags of a job's limits (`vint_core::limits`), shared by the coordinator and
//! the `vintctl` commands that judge a spec (`validate`, `plan`, `run`), so that both read the
//! same names and environment variables.

use vint_core::limits::Limits;

/// What one job may ask for; each flag raises (or lowers) one limit.
#[derive(Clone, Copy, Debug, clap::Args)]
pub struct LimitFlags {
    /// Most tasks one job may plan, every stage counted (an upper bound without a quota).
    #[arg(long, env = "VINT_MAX_TASKS_PER_JOB", default_value_t = Limits::default().tasks_per_job)]
    pub max_tasks_per_job: u64,
    /// Most samples one job may make (accepted grasps × views; an upper bound without a quota).
    #[arg(long, env = "VINT_MAX_SAMPLES_PER_JOB", default_value_t = Limits::default().samples_per_job)]
    pub max_samples_per_job: u64,
    /// Most objects one spec may list.
    #[arg(long, env = "VINT_MAX_OBJECTS", default_value_t = Limits::default().objects_per_spec)]
    pub max_objects: u64,
    /// Most hands one spec may list.
    #[arg(long, env = "VINT_MAX_HANDS", default_value_t = Limits::default().hands_per_spec)]
    pub max_hands: u64,
    /// Most pixel-samples one render task may cost: width × height × render.samples × views per grasp.
    #[arg(long, env = "VINT_MAX_RENDER_PIXEL_SAMPLES", default_value_t = Limits::default().render_pixel_samples_per_task)]
    pub max_render_pixel_samples: u64,
}

impl LimitFlags {
    pub fn limits(&self) -> Limits {
        Limits {
            tasks_per_job: self.max_tasks_per_job,
            samples_per_job: self.max_samples_per_job,
            objects_per_spec: self.max_objects,
            hands_per_spec: self.max_hands,
            render_pixel_samples_per_task: self.max_render_pixel_samples,
        }
    }
}
