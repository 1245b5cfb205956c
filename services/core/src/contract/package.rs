//! The package stage (in Rust, `workers/runtime/src/package.rs`): one directory per sample with
//! its requested files and `meta.json`, and one record per grasp that its samples refer to.
//!
//! Output names are `<sample_id>/<file>` and `<grasp_id>/grasp.json`: a sample id is its grasp id
//! plus `.vNN`, so an exported dataset has `tomato_soup_can.trx3.g000003/grasp.json` (touch,
//! contacts, joints, link poses: stored once) next to `tomato_soup_can.trx3.g000003.v00/meta.json`
//! (the view: camera, visibility, poses) and its images.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::depth::DepthFormat;
use super::render::{RenderOutput, ViewFile};

/// The package stage's engine identity (`crate::reuse`): the format of the files the package
/// stage (in `vint-runtime`) writes. Its number goes up whenever those files change for the same
/// inputs; the runtime's `the_package_format_is_pinned` test holds the two together.
pub const ENGINE_IDENTITY: &str = "vint-package-format-2";

/// A sample's metadata file.
pub const META_FILE: &str = "meta.json";
/// A grasp's record, shared by the samples of its views.
pub const GRASP_RECORD_FILE: &str = "grasp.json";

/// Where an exported dataset keeps an object's model mesh (binary PLY, millimetres, object frame),
/// relative to its root: once per object, not once per grasp.
pub fn model_path(object: &str) -> String {
    format!("models/{object}.ply")
}

/// What a dataset spec can ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Modality {
    Rgb,
    Depth,
    DepthNoisy,
    /// The object's visible and full masks.
    Mask,
    Segmentation,
    /// Poses and camera in `meta.json` (always written).
    Pose,
}

impl Modality {
    pub const ALL: [Modality; 6] =
        [Modality::Rgb, Modality::Depth, Modality::DepthNoisy, Modality::Mask, Modality::Segmentation, Modality::Pose];

    pub fn as_str(self) -> &'static str {
        match self {
            Modality::Rgb => "rgb",
            Modality::Depth => "depth",
            Modality::DepthNoisy => "depth_noisy",
            Modality::Mask => "mask",
            Modality::Segmentation => "segmentation",
            Modality::Pose => "pose",
        }
    }

    pub fn parse(name: &str) -> Option<Modality> {
        Modality::ALL.into_iter().find(|m| m.as_str() == name)
    }

    /// The render outputs this modality needs: noisy depth needs the clean depth it perturbs (and,
    /// when the noise model's `materials` piece is on, the segmentation: `plan::JobPlan` adds it).
    pub fn render_outputs(self) -> &'static [RenderOutput] {
        match self {
            Modality::Rgb => &[RenderOutput::Rgb],
            Modality::Depth => &[RenderOutput::Depth],
            Modality::DepthNoisy => &[RenderOutput::Depth],
            Modality::Mask => &[RenderOutput::Mask],
            Modality::Segmentation => &[RenderOutput::Segmentation],
            Modality::Pose => &[],
        }
    }

    /// The files this modality adds to a sample, depth stored as `depth`, and where each comes from.
    pub fn sample_files(self, depth: DepthFormat) -> &'static [SampleFile] {
        use DepthFormat::{Npy, Png};
        const RGB: &[SampleFile] = &[SampleFile { name: "rgb.png", from: Source::Render(ViewFile::Rgb) }];
        const DEPTH_PNG: &[SampleFile] =
            &[SampleFile { name: "depth.png", from: Source::Render(ViewFile::Depth(Png)) }];
        const DEPTH_NPY: &[SampleFile] =
            &[SampleFile { name: "depth.npy", from: Source::Render(ViewFile::Depth(Npy)) }];
        const NOISY_PNG: &[SampleFile] = &[SampleFile { name: "depth_noisy.png", from: Source::Noise(Png) }];
        const NOISY_NPY: &[SampleFile] = &[SampleFile { name: "depth_noisy.npy", from: Source::Noise(Npy) }];
        const MASK: &[SampleFile] = &[
            SampleFile { name: "mask.png", from: Source::Render(ViewFile::Mask) },
            SampleFile { name: "mask_full.png", from: Source::Render(ViewFile::MaskFull) },
        ];
        const SEGMENTATION: &[SampleFile] =
            &[SampleFile { name: "segmentation.png", from: Source::Render(ViewFile::Segmentation) }];
        match self {
            Modality::Rgb => RGB,
            Modality::Depth => match depth {
                Png => DEPTH_PNG,
                Npy => DEPTH_NPY,
            },
            Modality::DepthNoisy => match depth {
                Png => NOISY_PNG,
                Npy => NOISY_NPY,
            },
            Modality::Mask => MASK,
            Modality::Segmentation => SEGMENTATION,
            Modality::Pose => &[],
        }
    }
}

/// A file of a packaged sample: its name in the sample's directory and the artifact it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleFile {
    pub name: &'static str,
    pub from: Source,
}

/// Which task's output a sample file is, for the sample's view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    Render(ViewFile),
    /// The noise task's `v{NN}_depth_noisy.{png,npy}`.
    Noise(DepthFormat),
}

impl Source {
    /// The task key and file name this file is, for sample `id`: its grasp's render or noise
    /// task's file of the sample's view.
    pub fn origin(self, id: &crate::sample::SampleId) -> (String, String) {
        match self {
            Source::Render(file) => {
                (super::render::task_key(&id.object, &id.hand, id.grasp_index), file.name(id.view_index))
            }
            Source::Noise(format) => (
                super::noise::task_key(&id.object, &id.hand, id.grasp_index),
                super::noise::noisy_depth_file(id.view_index, format),
            ),
        }
    }
}

/// A package task's parameters: the samples of one grasp chunk and what they hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "PackageParams")]
pub struct Params {
    pub samples: Vec<SampleRef>,
    pub modalities: Vec<Modality>,
    /// How the samples' depth images are stored: as their render and noise tasks wrote them.
    #[serde(default)]
    pub depth_format: DepthFormat,
}

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SampleRef {
    pub sample_id: String,
    pub grasp_index: u32,
    pub view_index: u32,
}

/// What a package task made: its samples and the grasp records they refer to.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PackageResult {
    pub samples: Vec<String>,
    pub grasps: Vec<String>,
}

/// A sample's `meta.json` and a grasp's record: medians of tiny.toml's (docs/benchmarks.md,
/// "Output size per sample", 2026-11-29): the view alone (5.3–5.8 KB); the record once per grasp
/// (75–91 KB of indented JSON: the touch reading with each taxel's placement offset and the
/// contact samples, the trial's contacts and link poses).
pub const META_JSON_BYTES: f64 = 5_419.0;
pub const GRASP_RECORD_BYTES: f64 = 86_217.0;

/// A package task writes, per sample, its `meta.json` and the files of its modalities, and one
/// record per grasp of its samples.
pub fn files_written(task: &Params) -> u64 {
    let per_sample = 1 + task.modalities.iter().map(|m| m.sample_files(task.depth_format).len()).sum::<usize>();
    let grasps: std::collections::BTreeSet<u32> = task.samples.iter().map(|s| s.grasp_index).collect();
    (task.samples.len() * per_sample + grasps.len()) as u64
}

/// Per sample. docs/benchmarks.md, "tiny.toml": 244 ms for 72 samples.
const S_PER_SAMPLE: f64 = 0.0034;

/// Every sample packaged. Content addressing stores a packaged image once: it is the render's or
/// noise's object under the same hash, so the package stage adds only its JSON.
pub fn cost(work: &super::Workload) -> super::Cost {
    let samples = work.samples as f64;
    super::Cost {
        cpu_s: S_PER_SAMPLE * samples,
        bytes: samples * META_JSON_BYTES + work.grasps as f64 * GRASP_RECORD_BYTES,
    }
}
