//! One typed contract per stage: what a task of the stage is given (its parameters, with every
//! bound and default as a constant), what its engine answers (the stage's result, in the reply
//! frame), the files it writes and which of its dependencies' files it reads.
//!
//! This module is the one definition of those things. The spec schema (`spec`) takes its bounds
//! from the constants here, the planner (`plan`) builds task parameters as these types, the worker
//! asks `reads` which inputs to stage, the coordinator reads results as these types, and the
//! Python engines validate parameters against the JSON Schema generated from them
//! (`schema()`, committed as `workers/engines/vint_engines/contract.schema.json`; a test fails
//! when the committed file is stale). So a spec that validates yields parameters every engine
//! accepts by construction.
//!
//! Adding a stage kind means: a variant of `Stage`, a module here (params, result, files, reads),
//! its arms in the three matches below, and an engine package with its PROTOCOL.md section.

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
        for file in [render::ViewFile::Depth, render::ViewFile::Segmentation, render::ViewFile::Camera] {
            assert!(reads(Stage::Noise, &file.name(7)) && reads(Stage::Noise, &file.name(42)), "{}", file.name(7));
        }
        for file in [render::ViewFile::Rgb, render::ViewFile::Mask, render::ViewFile::MaskFull] {
            assert!(!reads(Stage::Noise, &file.name(7)), "{}", file.name(7));
        }
        assert!(!reads(Stage::Noise, &noise::noisy_depth_file(7)) && !reads(Stage::Noise, grasp::TOUCH_FILE));
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
