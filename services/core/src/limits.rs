//! What one job may ask for: limits a coordinator enforces before it plans or allocates anything,
//! counted from the spec alone (`cost`). A spec's own bounds (`spec`) keep each field sane; these
//! bound their products — a spec of 26 objects × 2 hands with `trials_per_pair = 1_000_000` and
//! `chunk_size = 1` is valid field by field and plans 5.2·10⁷ grasp tasks, which one submit would
//! allocate and insert in one transaction.
//!
//! Every limit has a default that admits the paper's recipe (`examples/vint-sim.toml`: 292,552
//! tasks, 1,560,000 samples, 26 objects, 2 hands, 1.2·10⁸ pixel-samples a render task) with room,
//! and a coordinator flag that raises it; `vintctl validate`, `plan` and `run` take the same flags.

use std::fmt;

use crate::cost::SpecCost;
use crate::spec::DatasetSpec;

/// The limits of one job.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Tasks of every stage, counted as the planner makes them (an upper bound without a quota).
    pub tasks_per_job: u64,
    /// Samples: accepted grasps × views (an upper bound without a quota).
    pub samples_per_job: u64,
    /// Objects a spec lists.
    pub objects_per_spec: u64,
    /// Hands a spec lists.
    pub hands_per_spec: u64,
    /// One render task's pixel-samples: width × height × samples per pixel × views per grasp.
    pub render_pixel_samples_per_task: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            tasks_per_job: 2_000_000,
            samples_per_job: 10_000_000,
            objects_per_spec: 1_000,
            hands_per_spec: 16,
            // About 10 CPU-hours of Cycles a task at the measured 1.8 µs a pixel-sample
            // (`contract::render`'s cost), e.g. 1920×1080 at 512 spp for 12 views.
            render_pixel_samples_per_task: 20_000_000_000,
        }
    }
}

/// One limit a spec exceeds: what, the spec's count, the limit and the flag that raises it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OverLimit {
    pub what: &'static str,
    pub count: u64,
    pub limit: u64,
    pub flag: &'static str,
}

impl fmt::Display for OverLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: the spec asks for {}, over the limit of {} (the coordinator's {} raises it)",
            self.what, self.count, self.limit, self.flag
        )
    }
}

/// Every limit `spec` exceeds (empty when none), from its counts (`cost`): nothing is planned.
pub fn check(limits: &Limits, spec: &DatasetSpec, cost: &SpecCost) -> Vec<OverLimit> {
    let tasks: u64 = cost.stages.iter().map(|s| s.tasks).sum();
    let render = u64::from(spec.render.resolution[0])
        .saturating_mul(u64::from(spec.render.resolution[1]))
        .saturating_mul(u64::from(spec.render.samples))
        .saturating_mul(u64::from(spec.render.views_per_grasp()));
    let counts = [
        ("tasks per job", tasks, limits.tasks_per_job, "--max-tasks-per-job"),
        ("samples per job", cost.work.samples, limits.samples_per_job, "--max-samples-per-job"),
        ("objects", spec.objects.len() as u64, limits.objects_per_spec, "--max-objects"),
        ("hands", spec.hands.len() as u64, limits.hands_per_spec, "--max-hands"),
        (
            "pixel-samples per render task (width × height × render.samples × views per grasp)",
            render,
            limits.render_pixel_samples_per_task,
            "--max-render-pixel-samples",
        ),
    ];
    counts
        .into_iter()
        .filter(|(_, count, limit, _)| count > limit)
        .map(|(what, count, limit, flag)| OverLimit { what, count, limit, flag })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(text: &str) -> DatasetSpec {
        DatasetSpec::parse(text).unwrap()
    }

    #[test]
    fn the_recipe_fits_the_defaults() {
        let recipe = spec(include_str!("../../../examples/vint-sim.toml"));
        let cost = crate::cost::of(&recipe).unwrap();
        assert_eq!(check(&Limits::default(), &recipe, &cost), []);
    }

    #[test]
    fn a_spec_valid_field_by_field_but_huge_in_product_is_over_the_task_limit() {
        let huge = spec(
            "hands = [\"trx3\", \"allegro\"]\n\
             objects = [\"mug\", \"bowl\", \"banana\", \"sugar_box\"]\n\
             [dataset]\nname = \"huge\"\nseed = 1\n\
             [grasp]\ntrials_per_pair = 1000000\nchunk_size = 1\n",
        );
        let cost = crate::cost::of(&huge).unwrap();
        let over = check(&Limits::default(), &huge, &cost);
        let tasks = over.iter().find(|o| o.what == "tasks per job").expect("over the task limit");
        assert!(tasks.count >= 8_000_000, "{tasks}");
        let text = tasks.to_string();
        assert!(text.contains("limit of 2000000") && text.contains("--max-tasks-per-job"), "{text}");
    }

    #[test]
    fn each_limit_names_its_own_count_and_flag() {
        let s = spec(include_str!("../../../examples/tiny.toml"));
        let cost = crate::cost::of(&s).unwrap();
        let none = Limits {
            tasks_per_job: 0,
            samples_per_job: 0,
            objects_per_spec: 0,
            hands_per_spec: 0,
            render_pixel_samples_per_task: 0,
        };
        let flags: Vec<&str> = check(&none, &s, &cost).iter().map(|o| o.flag).collect();
        assert_eq!(
            flags,
            [
                "--max-tasks-per-job",
                "--max-samples-per-job",
                "--max-objects",
                "--max-hands",
                "--max-render-pixel-samples"
            ]
        );
        let render = &check(&none, &s, &cost)[4];
        let r = &s.render;
        assert_eq!(
            render.count,
            u64::from(r.resolution[0] * r.resolution[1]) * u64::from(r.samples) * u64::from(r.views_per_grasp())
        );
    }
}
