//! One module per stage: what a task of the stage is given (its parameters, with every bound and
//! default as a constant), what its engine answers (the stage's result, in the reply frame), the
//! files it writes and their measured sizes, which of its dependencies' files it reads, what the
//! stage costs (`cost`) and what the timing-only worker answers in its place (`fake`).
//!
//! This module is the one definition of those things, and the functions below are the one
//! dispatch over `Stage` to them. The spec schema (`spec`) takes its bounds
//! from the constants here, the planner (`plan`) builds task parameters as these types, the worker
//! asks `reads` which inputs to stage, the coordinator reads results as these types, and the
//! Python engines validate parameters against the JSON Schema generated from them
//! (`schema()`, committed as `workers/engines/vint_engines/contract.schema.json`; a test fails
//! when the committed file is stale). So a spec that validates yields parameters every engine
//! accepts by construction.
//!
//! Adding a stage kind means: a variant of `Stage`, a module here (params, result, files, reads,
//! cost, fake), its arms in the matches below, where its tasks sit in the DAG (`plan`), and an
//! engine package with its PROTOCOL.md section; ARCHITECTURE.md lists every file, and a test holds
//! the list.

pub mod depth;
pub mod grasp;
pub mod noise;
pub mod object;
pub mod package;
pub mod render;

use schemars::generate::SchemaSettings;
use schemars::{JsonSchema, SchemaGenerator};
use serde::de::DeserializeOwned;
use serde_json::{Value, json};

use crate::stage::Stage;

/// A number parameter's closed range `[min, max]` and its default.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bound<T> {
    pub min: T,
    pub max: T,
    pub default: T,
}

impl<T: PartialOrd + Copy> Bound<T> {
    pub const fn new(min: T, max: T, default: T) -> Bound<T> {
        Bound { min, max, default }
    }

    pub fn contains(&self, x: T) -> bool {
        self.min <= x && x <= self.max
    }
}

/// Seeds are kept below 2^53 so that every JSON reader holds them exactly (`seed::SEED_MASK`).
pub const SEED_MAX: u64 = crate::seed::SEED_MASK;

/// Which of its dependencies' output files a stage's engine reads: the worker stages these and
/// nothing else. The package stage reads what it needs from the store itself.
pub fn reads(stage: Stage, file: &str) -> bool {
    match stage {
        Stage::Grasp => false,
        Stage::Render => render::reads(file),
        Stage::Noise => noise::reads(file),
        Stage::Package => false,
    }
}

/// Why a stage's result does not follow its contract.
#[derive(Debug, thiserror::Error)]
#[error("{stage} result does not follow the contract: {source}")]
pub struct BadResult {
    pub stage: Stage,
    pub source: serde_json::Error,
}

/// Reads a stage's result (what its engine answered in the reply frame) as its contract type.
pub fn result<T: DeserializeOwned>(stage: Stage, value: &Value) -> Result<T, BadResult> {
    T::deserialize(value).map_err(|source| BadResult { stage, source })
}

/// Checks a result against the stage's contract without keeping it.
pub fn check_result(stage: Stage, value: &Value) -> Result<(), BadResult> {
    match stage {
        Stage::Grasp => result::<grasp::GraspResult>(stage, value).map(drop),
        Stage::Render => result::<render::RenderResult>(stage, value).map(drop),
        Stage::Noise => result::<noise::NoiseResult>(stage, value).map(drop),
        Stage::Package => result::<package::PackageResult>(stage, value).map(drop),
    }
}

/// Why a task's parameters cannot be read as its stage's contract.
#[derive(Debug, thiserror::Error)]
#[error("{stage} params do not follow the contract: {source}")]
pub struct BadParams {
    pub stage: Stage,
    pub source: serde_json::Error,
}

fn params<T: DeserializeOwned>(stage: Stage, value: &Value) -> Result<T, BadParams> {
    T::deserialize(value).map_err(|source| BadParams { stage, source })
}

/// What a job asks of its stages, counted: the ground every stage's `cost` stands on
/// (`crate::cost` counts it from a spec).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Workload {
    /// (object, hand) pairs.
    pub pairs: u64,
    pub objects: u64,
    /// Grasp tasks: exact, fixed at submit.
    pub chunks: u64,
    /// Trials the grasp tasks may run: the spec's bound.
    pub trials: u64,
    /// Accepted grasps: the quota's target, or every trial (an upper bound) without one.
    pub grasps: u64,
    pub views_per_grasp: u64,
    /// `grasps × views_per_grasp`.
    pub samples: u64,
    /// Pixels per view.
    pub pixels: f64,
}

/// What one stage of a job costs: CPU seconds on one core of the measured machine (2 vCPUs, AMD
/// EPYC, one render thread per engine; each stage's figures name their source) and the bytes it
/// adds to the object store.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Cost {
    pub cpu_s: f64,
    pub bytes: f64,
}

/// What the stage costs for `work`, given one of its tasks' parameters (the stage's settings:
/// every task of a job shares them).
pub fn cost(stage: Stage, work: &Workload, task: &Value) -> Result<Cost, BadParams> {
    Ok(match stage {
        Stage::Grasp => grasp::cost(work, &params(stage, task)?),
        Stage::Render => render::cost(work, &params(stage, task)?),
        Stage::Noise => noise::cost(work, &params(stage, task)?),
        Stage::Package => package::cost(work),
    })
}

/// How many files a task writes, from its parameters: what the database's footprint counts.
pub fn files_written(stage: Stage, task: &Value) -> Result<u64, BadParams> {
    Ok(match stage {
        Stage::Grasp => grasp::files_written(),
        Stage::Render => render::files_written(&params(stage, task)?),
        Stage::Noise => noise::files_written(&params(stage, task)?),
        Stage::Package => package::files_written(&params(stage, task)?),
    })
}

/// The kind of a file a stage writes, as the object store records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FileKind {
    Png,
    Npy,
    Json,
    Ply,
}

impl FileKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FileKind::Png => "png",
            FileKind::Npy => "npy",
            FileKind::Json => "json",
            FileKind::Ply => "ply",
        }
    }

    pub fn media_type(self) -> &'static str {
        match self {
            FileKind::Png => "image/png",
            FileKind::Npy => "application/x-npy",
            FileKind::Json => "application/json",
            FileKind::Ply => "application/x-ply",
        }
    }
}

/// A file the timing-only worker writes in place of an engine's: the real name, the measured size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FakeFile {
    pub name: String,
    pub kind: FileKind,
    pub size: u64,
}

/// What the timing-only worker answers for a task: a result of the stage's contract and files of
/// the real names and sizes.
#[derive(Clone, Debug, PartialEq)]
pub struct Fake {
    pub result: Value,
    pub files: Vec<FakeFile>,
}

/// Why the timing-only worker cannot answer a task.
#[derive(Debug, thiserror::Error)]
pub enum FakeError {
    #[error(transparent)]
    Params(#[from] BadParams),
    #[error("{stage} input {name} is missing")]
    MissingInput { stage: Stage, name: String },
    #[error("{stage} result: {source}")]
    Result { stage: Stage, source: serde_json::Error },
}

/// What the timing-only worker calls itself wherever an engine would name itself or its device.
pub const TIMING_ONLY: &str = "timing-only";

/// A task's staged input as the timing-only worker sees it: its name and size.
#[derive(Clone, Copy, Debug)]
pub struct FakeInput<'a> {
    pub name: &'a str,
    pub size: u64,
}

/// What the timing-only worker answers for a task of an engine stage, as its engine would:
/// grasp trials are accepted when their seed falls below `accept_rate` (so a run is
/// deterministic), images and documents have the sizes measured on real runs. `None` for the
/// package stage, which the worker runs for real (it moves no pixels).
pub fn fake(stage: Stage, task: &Value, inputs: &[FakeInput<'_>], accept_rate: f64) -> Result<Option<Fake>, FakeError> {
    let answer = |result: Result<Value, serde_json::Error>, files| match result {
        Ok(result) => Ok(Some(Fake { result, files })),
        Err(source) => Err(FakeError::Result { stage, source }),
    };
    match stage {
        Stage::Grasp => {
            let (result, files) = grasp::fake(&params(stage, task)?, accept_rate);
            answer(serde_json::to_value(result), files)
        }
        Stage::Render => {
            let (result, files) = render::fake(&params(stage, task)?);
            answer(serde_json::to_value(result), files)
        }
        Stage::Noise => {
            let (result, files) = noise::fake(&params(stage, task)?, inputs)?;
            answer(serde_json::to_value(result), files)
        }
        Stage::Package => Ok(None),
    }
}

/// Where the generated schema is committed, relative to the repository root.
pub const SCHEMA_PATH: &str = "workers/engines/vint_engines/contract.schema.json";

/// The JSON Schema (draft 2020-12) of every stage's parameters and result: `stages.<stage>.params`
/// and `.result` refer into `$defs`. Deterministic: the same code gives the same bytes.
pub fn schema() -> Value {
    let mut generator = SchemaGenerator::new(SchemaSettings::draft2020_12());
    let mut stages = serde_json::Map::new();
    let mut add = |stage: Stage, params: Value, result: Value| {
        stages.insert(stage.as_str().to_string(), json!({"params": params, "result": result}));
    };
    add(Stage::Grasp, sub::<grasp::Params>(&mut generator), sub::<grasp::GraspResult>(&mut generator));
    add(Stage::Render, sub::<render::Params>(&mut generator), sub::<render::RenderResult>(&mut generator));
    add(Stage::Noise, sub::<noise::Params>(&mut generator), sub::<noise::NoiseResult>(&mut generator));
    add(Stage::Package, sub::<package::Params>(&mut generator), sub::<package::PackageResult>(&mut generator));
    let defs: serde_json::Map<String, Value> = generator.take_definitions(true).into_iter().collect();
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "vint stage contracts",
        "description": "Parameters and results of every pipeline stage. Generated from vint_core::contract \
                        (services/core/src/contract): do not edit; regenerate with \
                        `VINT_BLESS=1 cargo test -p vint-core committed_schema`.",
        "stages": stages,
        "depth_modes": noise::modes_table(),
        "depth_png": json!({"unit_m": depth::PNG_UNIT_M, "max_m": depth::PNG_MAX_M}),
        "$defs": defs,
    })
}

fn sub<T: JsonSchema>(generator: &mut SchemaGenerator) -> Value {
    generator.subschema_for::<T>().to_value()
}

/// The schema as committed: pretty-printed with a final newline.
pub fn schema_text() -> String {
    let mut text = serde_json::to_string_pretty(&schema()).unwrap_or_default();
    text.push('\n');
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn committed_schema_is_the_generated_one() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(SCHEMA_PATH);
        let generated = schema_text();
        if std::env::var_os("VINT_BLESS").is_some() {
            std::fs::write(&path, &generated).expect("write the schema");
        }
        let committed = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            committed == generated,
            "{} is stale: regenerate it with `VINT_BLESS=1 cargo test -p vint-core committed_schema` and commit it",
            path.display()
        );
    }

    #[test]
    fn render_tasks_read_poses_and_the_mesh_but_not_touch_and_noise_tasks_read_depth_segmentation_camera() {
        assert!(reads(Stage::Render, grasp::GRASPS_FILE) && reads(Stage::Render, grasp::MODEL_FILE));
        assert!(!reads(Stage::Render, grasp::TOUCH_FILE), "touch.json is the bulk of a chunk's output");
        let depth = depth::DepthFormat::ALL.map(render::ViewFile::Depth);
        for file in depth.into_iter().chain([render::ViewFile::Segmentation, render::ViewFile::Camera]) {
            assert!(reads(Stage::Noise, &file.name(7)) && reads(Stage::Noise, &file.name(42)), "{}", file.name(7));
        }
        for file in [render::ViewFile::Rgb, render::ViewFile::Mask, render::ViewFile::MaskFull] {
            assert!(!reads(Stage::Noise, &file.name(7)), "{}", file.name(7));
        }
        for format in depth::DepthFormat::ALL {
            assert!(!reads(Stage::Noise, &noise::noisy_depth_file(7, format)));
        }
        assert!(!reads(Stage::Noise, grasp::TOUCH_FILE));
        assert!(!reads(Stage::Grasp, grasp::GRASPS_FILE) && !reads(Stage::Package, grasp::GRASPS_FILE));
    }

    #[test]
    fn every_stage_has_params_and_result_in_the_schema() {
        let schema = schema();
        for stage in Stage::ALL {
            for part in ["params", "result"] {
                let reference = schema["stages"][stage.as_str()][part]["$ref"].as_str().unwrap_or_default();
                let name = reference.trim_start_matches("#/$defs/");
                assert!(schema["$defs"].get(name).is_some(), "{stage}.{part}: {reference:?} resolves to nothing");
            }
        }
    }
}
