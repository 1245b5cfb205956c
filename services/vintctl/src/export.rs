//! Writing a job's packaged samples to a directory in the native layout: one directory per
//! sample, one per grasp record its samples share (`<grasp_id>/grasp.json`), each object's model
//! once (`models/<object>.ply`), the dataset's own record (`dataset.json`: objects with their BOP
//! ids, trials per pair, the split) and a `manifest.jsonl` listing every file with its SHA-256: a
//! line `{"dataset", "files"}`, then `{"model", "files"}` per object, then `{"grasp_id", "files"}`
//! per grasp record and `{"sample_id", "files"}` per sample in id order (a grasp's line comes just
//! before its samples'). The other formats (`formats`) are converted from this layout.
//!
//! The dataset is assembled in a sibling temporary directory and renamed into place, so a reader
//! never sees half a dataset. Every file is verified against its hash as it is read from storage.
//! It is given the samples (the coordinator lists them) and the store; it talks to no one else.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use vint_artifacts::ArtifactStore;
use vint_core::GraspId;
use vint_core::catalog::{self, USER_OBJECT_IDS};
use vint_core::contract::package::{GRASP_RECORD_FILE, model_path};
use vint_core::split::{self, SplitSettings};
use vint_proto::v1 as pb;

use crate::formats::{self, Format, Target};
use crate::{Failure, bad_input};

/// The dataset's own record, at its root.
pub const DATASET_FILE: &str = "dataset.json";
/// `dataset.json`'s `format` in the native layout (the converters write their own).
const NATIVE_FORMAT: &str = "vint-native";

/// What the export needs to know of the job besides its samples: the seed and how to split.
pub struct DatasetInfo<'a> {
    pub name: &'a str,
    pub seed: u64,
    pub split: &'a SplitSettings,
}

#[derive(Debug, Serialize)]
pub struct ExportSummary {
    pub job_id: String,
    pub out: PathBuf,
    pub format: &'static str,
    pub samples: usize,
    pub files: usize,
    pub bytes: u64,
    /// SHA-256 of manifest.jsonl: equal datasets have equal manifest hashes.
    pub manifest_sha256: String,
}

#[derive(Serialize)]
struct ManifestLine<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    dataset: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    model: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    grasp_id: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sample_id: Option<&'a str>,
    files: BTreeMap<&'a str, ManifestFile<'a>>,
}

#[derive(Serialize)]
struct ManifestFile<'a> {
    sha256: &'a str,
    size: u64,
    media_type: &'a str,
}

/// Writes the samples the coordinator `listed` for job `job_id`, read from `store`, to `out` in
/// `format` (replacing an earlier dataset there, never anything else).
pub async fn export(
    store: &ArtifactStore,
    job_id: &str,
    info: &DatasetInfo<'_>,
    listed: &pb::ListSamplesResponse,
    out: &Path,
    target: Target,
) -> Result<ExportSummary, Failure> {
    check_destination(out)?;
    let native = staging_dir(out, "native")?;
    let written = write_dataset(store, info, listed, &native).await;
    let (files, bytes, manifest) = match written {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&native);
            return Err(e);
        }
    };
    let samples = listed.samples.len();
    if target.format == Format::Native {
        replace_with(&native, out)?;
        return Ok(ExportSummary {
            job_id: job_id.to_string(),
            out: out.to_path_buf(),
            format: target.format.as_str(),
            samples,
            files,
            bytes,
            manifest_sha256: hex::encode(Sha256::digest(&manifest)),
        });
    }
    let converted = convert_dir(&native, out, target);
    let _ = std::fs::remove_dir_all(&native);
    let mut summary = converted?;
    summary.job_id = job_id.to_string();
    Ok(summary)
}

/// Converts the native dataset at `native` into `format` at `out` (replacing an earlier dataset
/// there, never anything else): `vintctl convert`, and the last step of a non-native export.
pub fn convert_dir(native: &Path, out: &Path, target: Target) -> Result<ExportSummary, Failure> {
    let format = target.format;
    check_destination(out)?;
    refuse_overlap(native, out)?;
    let layout = std::fs::read(native.join(DATASET_FILE))
        .ok()
        .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok())
        .and_then(|record| record["format"].as_str().map(str::to_string));
    if layout.as_deref() != Some(NATIVE_FORMAT) {
        let found =
            layout.map_or_else(|| format!("no readable {DATASET_FILE}"), |f| format!("its {DATASET_FILE} says {f:?}"));
        return Err(bad_input(anyhow!(
            "{}: not a vint dataset in the native layout ({found}; `vintctl run` and `vintctl export` write one \
             without --format)",
            native.display()
        )));
    }
    let staging = staging_dir(out, format.as_str())?;
    let converted = formats::convert(target, native, &staging).and_then(|c| {
        let manifest = formats::write_manifest(&staging)?;
        Ok((c, manifest))
    });
    let (converted, manifest) = match converted {
        Ok(c) => c,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e.context(format!("writing the {} dataset", format.as_str())).into());
        }
    };
    replace_with(&staging, out)?;
    Ok(ExportSummary {
        job_id: String::new(),
        out: out.to_path_buf(),
        format: format.as_str(),
        samples: converted.samples,
        files: converted.files,
        bytes: converted.bytes,
        manifest_sha256: hex::encode(Sha256::digest(&manifest)),
    })
}

/// Refuses an output that is the input, or holds it, or lies in it: replacing it would delete the
/// dataset being converted.
fn refuse_overlap(native: &Path, out: &Path) -> Result<(), Failure> {
    let resolve = |p: &Path| {
        let absolute = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        absolute.canonicalize().unwrap_or(absolute)
    };
    let (native, out) = (resolve(native), resolve(out));
    if native.starts_with(&out) || out.starts_with(&native) {
        return Err(bad_input(anyhow!(
            "--out {}: overlaps the dataset being converted ({}); write the conversion elsewhere",
            out.display(),
            native.display()
        )));
    }
    Ok(())
}

/// A fresh sibling of `out` to assemble a dataset in, so that a reader never sees half of one.
fn staging_dir(out: &Path, what: &str) -> Result<PathBuf, Failure> {
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    let staging = sibling(out, &format!("partial-{what}"));
    if staging.exists() {
        std::fs::remove_dir_all(&staging).with_context(|| format!("removing stale {}", staging.display()))?;
    }
    Ok(staging)
}

/// Moves the finished dataset at `staging` to `out`. A dataset already there is checked again
/// (it may have changed while this one was written), moved aside, replaced, and only then
/// removed: a failure before the last step leaves it where it was.
fn replace_with(staging: &Path, out: &Path) -> Result<(), Failure> {
    if !out.exists() {
        std::fs::rename(staging, out).with_context(|| format!("moving the dataset into {}", out.display()))?;
        return Ok(());
    }
    check_destination(out)?;
    let aside = sibling(out, "replaced");
    if aside.exists() {
        std::fs::remove_dir_all(&aside).with_context(|| format!("removing stale {}", aside.display()))?;
    }
    std::fs::rename(out, &aside).with_context(|| format!("moving the dataset at {} aside", out.display()))?;
    if let Err(e) = std::fs::rename(staging, out) {
        let _ = std::fs::rename(&aside, out);
        return Err(anyhow::Error::new(e).context(format!("moving the dataset into {}", out.display())).into());
    }
    if let Err(e) = std::fs::remove_dir_all(&aside) {
        tracing::warn!(path = %aside.display(), error = %e, "could not remove the replaced dataset");
    }
    Ok(())
}

/// A hidden sibling of `out` for `what` (staging, a replaced dataset), named by this process.
fn sibling(out: &Path, what: &str) -> PathBuf {
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    parent.join(format!(
        ".{}.{what}-{}",
        out.file_name().and_then(|n| n.to_str()).unwrap_or("dataset"),
        std::process::id()
    ))
}

/// Refuses `--out` unless it is absent, an empty directory, or a dataset vint wrote: a directory
/// whose `manifest.jsonl` is one of ours (the native layout's lines, or a converted format's
/// `{path, sha256, size}` lines) and lists every file the directory holds. A directory that merely
/// holds a file named `manifest.jsonl` (a common name among ML datasets), or a dataset someone
/// added files to, is refused with the first file that would be lost; nothing is changed.
pub fn check_destination(out: &Path) -> Result<(), Failure> {
    let refuse = |why: String| {
        bad_input(anyhow!("--out {}: {why}; refusing to replace it (nothing was changed)", out.display()))
    };
    let Ok(meta) = std::fs::symlink_metadata(out) else { return Ok(()) };
    if !meta.is_dir() {
        return Err(bad_input(anyhow!("--out {}: exists and is not a directory", out.display())));
    }
    let held = formats::relative_files(out)?;
    if held.is_empty() {
        return Ok(());
    }
    let manifest = match std::fs::read_to_string(out.join("manifest.jsonl")) {
        Ok(text) => text,
        Err(_) => return Err(refuse("is a non-empty directory without a manifest.jsonl".into())),
    };
    let listed = manifest_paths(&manifest)
        .map_err(|why| refuse(format!("its manifest.jsonl is not one vint writes ({why})")))?;
    if let Some((extra, _)) = held.iter().find(|(p, _)| p != "manifest.jsonl" && !listed.contains(p.as_str())) {
        return Err(refuse(format!("holds {extra:?}, which its manifest.jsonl does not list")));
    }
    Ok(())
}

/// The paths a vint manifest lists, or why it is not one: a native line names its files in its
/// entry's directory (the dataset's at the root, a model's in `models/`, a grasp's or a sample's
/// under its id), a converted format's line names one path.
fn manifest_paths(text: &str) -> Result<BTreeSet<String>, String> {
    let mut paths = BTreeSet::new();
    for (n, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let value: Value = serde_json::from_str(line).map_err(|e| format!("line {}: {e}", n + 1))?;
        if let Some(path) = value.get("path").and_then(Value::as_str) {
            if value.get("sha256").and_then(Value::as_str).is_none()
                || value.get("size").and_then(Value::as_u64).is_none()
            {
                return Err(format!("line {}: a path without its sha256 and size", n + 1));
            }
            paths.insert(path.to_string());
            continue;
        }
        let Some(files) = value.get("files").and_then(Value::as_object) else {
            return Err(format!("line {}: neither a path nor files", n + 1));
        };
        let dir = if value.get("model").is_some() {
            "models"
        } else if let Some(id) = value.get("grasp_id").or_else(|| value.get("sample_id")).and_then(Value::as_str) {
            id
        } else if value.get("dataset").is_some() {
            ""
        } else {
            return Err(format!("line {}: files of no dataset, model, grasp or sample", n + 1));
        };
        for name in files.keys() {
            paths.insert(if dir.is_empty() { name.clone() } else { format!("{dir}/{name}") });
        }
    }
    if paths.is_empty() {
        return Err("it lists no file".into());
    }
    Ok(paths)
}

/// What a manifest line lists: an object's model, a grasp record's or a sample's directory.
#[derive(Clone, Copy, PartialEq, Eq)]
enum EntryKind {
    Model,
    Grasp,
    Sample,
}

/// A directory of the dataset and its files, under their names there.
struct Entry<'a> {
    id: &'a str,
    kind: EntryKind,
    files: Vec<(String, &'a pb::ArtifactRef)>,
}

impl Entry<'_> {
    fn dir(&self) -> &str {
        if self.kind == EntryKind::Model { "models" } else { self.id }
    }
}

async fn write_dataset(
    store: &ArtifactStore,
    info: &DatasetInfo<'_>,
    listed: &pb::ListSamplesResponse,
    dir: &Path,
) -> Result<(usize, u64, Vec<u8>), Failure> {
    let mut entries: Vec<Entry> = Vec::with_capacity(listed.samples.len() + listed.grasps.len() + listed.models.len());
    let mut grasp_ids = Vec::with_capacity(listed.grasps.len());
    for g in &listed.grasps {
        let id: GraspId =
            g.grasp_id.parse().map_err(|_| anyhow!("coordinator returned a malformed grasp id {:?}", g.grasp_id))?;
        grasp_ids.push(id);
        let files = g.file.iter().map(|f| (f.name.clone(), f)).collect();
        entries.push(Entry { id: &g.grasp_id, kind: EntryKind::Grasp, files });
    }
    for s in &listed.samples {
        if s.sample_id.parse::<vint_core::SampleId>().is_err() {
            return Err(anyhow!("coordinator returned a malformed sample id {:?}", s.sample_id).into());
        }
        let files = s.files.iter().map(|f| (f.name.clone(), f)).collect();
        entries.push(Entry { id: &s.sample_id, kind: EntryKind::Sample, files });
    }
    entries.sort_by(|a, b| a.id.cmp(b.id));
    let mut models: Vec<Entry> = Vec::new();
    for m in &listed.models {
        let Some(file) = &m.file else { continue };
        let name = model_path(&m.object);
        let name = name.trim_start_matches("models/").to_string();
        models.push(Entry { id: &m.object, kind: EntryKind::Model, files: vec![(name, file)] });
    }
    models.sort_by(|a, b| a.id.cmp(b.id));
    let mut lines = Vec::new();
    let (mut files, mut bytes) = (0usize, 0u64);
    for entry in models.iter().chain(&entries) {
        let id = Some(entry.id);
        let mut line = ManifestLine {
            dataset: None,
            model: id.filter(|_| entry.kind == EntryKind::Model),
            grasp_id: id.filter(|_| entry.kind == EntryKind::Grasp),
            sample_id: id.filter(|_| entry.kind == EntryKind::Sample),
            files: BTreeMap::new(),
        };
        for (name, f) in &entry.files {
            if name.contains('/') || name.starts_with('.') {
                return Err(anyhow!("{}: refusing file name {:?}", entry.id, name).into());
            }
            let path = dir.join(entry.dir()).join(name);
            store.get_to_file(&f.sha256, &path).await.with_context(|| format!("{}: fetching {}", entry.id, name))?;
            files += 1;
            bytes += f.size;
            line.files.insert(name, ManifestFile { sha256: &f.sha256, size: f.size, media_type: &f.media_type });
        }
        serde_json::to_writer(&mut lines, &line).context("encoding manifest")?;
        lines.push(b'\n');
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let record = dataset_record(info, listed, &grasp_ids, dir)?;
    let record = serde_json::to_vec_pretty(&record).context("encoding dataset.json")?;
    std::fs::write(dir.join(DATASET_FILE), &record).context("writing dataset.json")?;
    let sha = hex::encode(Sha256::digest(&record));
    let size = record.len() as u64;
    let mut head =
        ManifestLine { dataset: Some(info.name), model: None, grasp_id: None, sample_id: None, files: BTreeMap::new() };
    head.files.insert(DATASET_FILE, ManifestFile { sha256: &sha, size, media_type: "application/json" });
    let mut manifest = serde_json::to_vec(&head).context("encoding manifest")?;
    manifest.push(b'\n');
    manifest.extend_from_slice(&lines);
    std::fs::write(dir.join("manifest.jsonl"), &manifest).context("writing manifest.jsonl")?;
    Ok((files + 1, bytes + size, manifest))
}

/// `dataset.json`: the objects with their BOP ids, where their models come from (a built-in
/// object's procedural model, and the ycbv object it stands in for; a user's mesh) and model
/// facts, the trials per pair, and each grasp's split. Everything in it derives from the job's content (no ids of runs or times), so
/// equal jobs write equal records.
fn dataset_record(
    info: &DatasetInfo<'_>,
    listed: &pb::ListSamplesResponse,
    grasps: &[GraspId],
    dir: &Path,
) -> Result<Value, Failure> {
    let mut objects = Vec::new();
    let records: BTreeMap<&str, Value> = listed
        .models
        .iter()
        .map(|m| Ok((m.object.as_str(), object_record(grasps, &m.object, dir)?)))
        .collect::<Result<_, Failure>>()?;
    // A spec's own object keeps the BOP id its entry names (a BOP dataset's model); the others are
    // numbered in name order from USER_OBJECT_IDS.
    let own_id =
        |name: &str| records.get(name).and_then(|r| r["obj_id"].as_u64()).and_then(|id| u32::try_from(id).ok());
    let mut user_objects: Vec<&str> = listed
        .models
        .iter()
        .map(|m| m.object.as_str())
        .filter(|o| catalog::objects().iter().all(|c| c.name != *o) && own_id(o).is_none())
        .collect();
    user_objects.sort_unstable();
    let mut taken: BTreeMap<u32, &str> = BTreeMap::new();
    for m in &listed.models {
        // A built-in object is a procedural stand-in with an id of its own, never the id of the
        // ycbv model it approximates; `stand_in_for` names that model.
        let (obj_id, source, stand_in) = match (catalog::object(&m.object), own_id(&m.object)) {
            (Some(entry), _) => (catalog::obj_id(&m.object), "procedural", catalog::stand_in_for(entry)),
            (None, Some(id)) => (Some(id), "bop", None),
            (None, None) => {
                let position = user_objects.iter().position(|o| *o == m.object).unwrap_or(0);
                (u32::try_from(position).ok().map(|p| USER_OBJECT_IDS + p), "user", None)
            }
        };
        if let Some(other) = obj_id.and_then(|id| taken.insert(id, &m.object)) {
            return Err(bad_input(anyhow!(
                "objects {other} and {} both have obj_id {}: a BOP dataset names each model by one id",
                m.object,
                obj_id.unwrap_or_default()
            )));
        }
        let record = records[m.object.as_str()].clone();
        let model = &record["model"];
        // Micrometre resolution: the record's metres have nine decimals, and ×1000 adds float noise.
        let mm = |v: &Value| v.as_f64().map(|m| (m * 1e9).round() / 1e6);
        // A BOP dataset's model keeps its file's frame: the record says where the file's origin is
        // (`file_offset_m`, the bounding-box centre in the file's coordinates). This layout stays in
        // the object frame (models, poses and, moved into it, the symmetries) and names the
        // offset; the BOP conversion writes everything in the file's frame.
        let offset = model["file_offset_m"].as_array().filter(|_| source == "bop").and_then(|c| {
            let c: Vec<f64> = c.iter().filter_map(Value::as_f64).collect();
            <[f64; 3]>::try_from(c).ok()
        });
        let symmetries = |key: &str| -> Result<Value, Failure> {
            match offset {
                Some(c) if c != [0.0; 3] => {
                    let moved = formats::bop::moved_symmetries(key, &record[key], c.map(|v| -v))
                        .ok_or_else(|| anyhow!("object {}: {key} is not in BOP's form", m.object))?;
                    Ok(moved)
                }
                _ => Ok(record[key].clone()),
            }
        };
        let (continuous, discrete) = (symmetries("symmetries_continuous")?, symmetries("symmetries_discrete")?);
        let mut object = json!({
            "name": m.object,
            "obj_id": obj_id,
            "model_source": source,
            "stand_in_for": stand_in,
            "ycb_id": record["ycb_id"],
            "model": model_path(&m.object),
            "units": "mm",
            "diameter_mm": mm(&model["diameter_m"]),
            "extent_mm": model["extent_m"].as_array().map(|e| e.iter().map(mm).collect::<Vec<_>>()),
            "symmetries_continuous": continuous,
            "symmetries_discrete": discrete,
        });
        if let Some(c) = offset {
            object["file_offset_mm"] = json!(c.map(|v| (v * 1e9).round() / 1e6 + 0.0));
        }
        objects.push(object);
    }
    objects.sort_by_key(|o| o["obj_id"].as_u64());
    let pairs: Vec<Value> = listed
        .pairs
        .iter()
        .map(|p| json!({"object": p.object, "hand": p.hand, "trials": p.trials, "accepted": p.accepted, "rejected": p.rejected}))
        .collect();
    let assigned = split::assign(grasps, info.seed, info.split);
    let by_grasp: BTreeMap<String, &str> = assigned.iter().map(|(g, s)| (g.to_string(), s.as_str())).collect();
    Ok(json!({
        "format": NATIVE_FORMAT,
        "version": 1,
        "name": info.name,
        "seed": info.seed,
        "objects": objects,
        "pairs": pairs,
        "split": {
            "seed": info.seed,
            "fractions": {"train": info.split.train, "val": info.split.val, "test": info.split.test},
            "held_out_objects": info.split.held_out_objects,
            "held_out_hands": info.split.held_out_hands,
            "grasps": by_grasp,
        },
    }))
}

/// The object's record as a grasp of it holds it (symmetries, model facts); null fields when the
/// job packaged no grasp of it.
fn object_record(grasps: &[GraspId], object: &str, dir: &Path) -> Result<Value, Failure> {
    let Some(grasp) = grasps.iter().find(|g| g.object == object) else {
        return Ok(Value::Null);
    };
    let path = dir.join(grasp.to_string()).join(GRASP_RECORD_FILE);
    let text = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let record: Value = serde_json::from_slice(&text).with_context(|| format!("parsing {}", path.display()))?;
    Ok(record["object"].clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, rel: &str, text: &str) {
        let path = dir.join(rel);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }

    fn native_manifest() -> &'static str {
        concat!(
            r#"{"dataset":"d","files":{"dataset.json":{"sha256":"aa","size":2,"media_type":"application/json"}}}"#,
            "\n",
            r#"{"model":"box","files":{"obj_000001.ply":{"sha256":"bb","size":2,"media_type":"model/ply"}}}"#,
            "\n",
            r#"{"sample_id":"s1","files":{"rgb.png":{"sha256":"cc","size":2,"media_type":"image/png"}}}"#,
            "\n",
        )
    }

    #[test]
    fn a_directory_with_a_foreign_manifest_is_refused_and_keeps_its_files() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        write(&out, "manifest.jsonl", "{\"id\": 7, \"text\": \"a caption\"}\n");
        write(&out, "data.txt", "precious");
        let e = check_destination(&out).unwrap_err();
        assert_eq!(e.code, 2);
        let message = format!("{:#}", e.error);
        assert!(message.contains("not one vint writes") && message.contains("nothing was changed"), "{message}");
        assert_eq!(std::fs::read_to_string(out.join("data.txt")).unwrap(), "precious");
    }

    #[test]
    fn a_vint_dataset_is_replaceable_until_a_file_it_does_not_list_is_added() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        write(&out, "manifest.jsonl", native_manifest());
        write(&out, "dataset.json", "{}");
        write(&out, "models/obj_000001.ply", "ply");
        write(&out, "s1/rgb.png", "png");
        check_destination(&out).unwrap();
        write(&out, "s1/notes.txt", "mine");
        let message = format!("{:#}", check_destination(&out).unwrap_err().error);
        assert!(message.contains("\"s1/notes.txt\"") && message.contains("does not list"), "{message}");
    }

    #[test]
    fn a_converted_dataset_lists_its_paths_and_an_empty_or_absent_directory_is_free() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("bop");
        write(&out, "manifest.jsonl", "{\"path\":\"train/000001/scene_gt.json\",\"sha256\":\"aa\",\"size\":2}\n");
        write(&out, "train/000001/scene_gt.json", "{}");
        check_destination(&out).unwrap();
        check_destination(&dir.path().join("absent")).unwrap();
        std::fs::create_dir_all(dir.path().join("empty/sub")).unwrap();
        check_destination(&dir.path().join("empty")).unwrap();
        write(&dir.path().join("plain"), "data.txt", "x");
        let message = format!("{:#}", check_destination(&dir.path().join("plain")).unwrap_err().error);
        assert!(message.contains("without a manifest.jsonl"), "{message}");
    }

    #[test]
    fn replacing_a_dataset_moves_it_aside_first_and_leaves_no_sibling_behind() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        write(&out, "manifest.jsonl", "{\"path\":\"a.txt\",\"sha256\":\"aa\",\"size\":1}\n");
        write(&out, "a.txt", "old");
        let staging = dir.path().join("staging");
        write(&staging, "manifest.jsonl", "{\"path\":\"b.txt\",\"sha256\":\"bb\",\"size\":1}\n");
        write(&staging, "b.txt", "new");
        replace_with(&staging, &out).unwrap();
        assert_eq!(std::fs::read_to_string(out.join("b.txt")).unwrap(), "new");
        assert!(!out.join("a.txt").exists());
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left, [std::ffi::OsString::from("out")]);
        // A file added to the dataset meanwhile stops the replacement, and both stay as they were.
        write(&out, "added.txt", "mine");
        write(&staging, "manifest.jsonl", "{\"path\":\"c.txt\",\"sha256\":\"cc\",\"size\":1}\n");
        assert!(replace_with(&staging, &out).is_err());
        assert_eq!(std::fs::read_to_string(out.join("added.txt")).unwrap(), "mine");
        assert!(staging.join("manifest.jsonl").exists());
    }
}
