//! Writing a job's packaged samples to a directory: one directory per sample, one per grasp
//! record its samples share (`<grasp_id>/grasp.json`), and a `manifest.jsonl` listing every file
//! with its SHA-256: a line `{"grasp_id", "files"}` per grasp record and `{"sample_id", "files"}`
//! per sample, in id order (a grasp's line comes just before its samples').
//!
//! The dataset is assembled in a sibling temporary directory and renamed into place, so a reader
//! never sees half a dataset. Every file is verified against its hash as it is read from storage.
//! It is given the samples (the coordinator lists them) and the store; it talks to no one else.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;
use sha2::{Digest, Sha256};
use vint_artifacts::ArtifactStore;
use vint_proto::v1 as pb;

use crate::{Failure, bad_input};

#[derive(Debug, Serialize)]
pub struct ExportSummary {
    pub job_id: String,
    pub out: PathBuf,
    pub samples: usize,
    pub files: usize,
    pub bytes: u64,
    /// SHA-256 of manifest.jsonl: equal datasets have equal manifest hashes.
    pub manifest_sha256: String,
}

#[derive(Serialize)]
struct ManifestLine<'a> {
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

/// Writes the samples the coordinator `listed` for job `job_id`, read from `store`, to `out`
/// (replacing an earlier dataset there, never anything else).
pub async fn export(
    store: &ArtifactStore,
    job_id: &str,
    listed: &pb::ListSamplesResponse,
    out: &Path,
) -> Result<ExportSummary, Failure> {
    check_destination(out)?;
    let samples = &listed.samples;
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    let staging = parent.join(format!(
        ".{}.partial-{}",
        out.file_name().and_then(|n| n.to_str()).unwrap_or("dataset"),
        std::process::id()
    ));
    if staging.exists() {
        std::fs::remove_dir_all(&staging).with_context(|| format!("removing stale {}", staging.display()))?;
    }
    let written = write_dataset(store, samples, &listed.grasps, &staging).await;
    let (files, bytes, manifest) = match written {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("replacing {}", out.display()))?;
    }
    std::fs::rename(&staging, out).with_context(|| format!("moving the dataset into {}", out.display()))?;
    Ok(ExportSummary {
        job_id: job_id.to_string(),
        out: out.to_path_buf(),
        samples: samples.len(),
        files,
        bytes,
        manifest_sha256: hex::encode(Sha256::digest(&manifest)),
    })
}

/// Refuses to replace a non-empty directory that is not a vint dataset.
pub fn check_destination(out: &Path) -> Result<(), Failure> {
    if !out.exists() {
        return Ok(());
    }
    if !out.is_dir() {
        return Err(bad_input(anyhow!("--out {}: exists and is not a directory", out.display())));
    }
    let empty = std::fs::read_dir(out).map(|mut d| d.next().is_none()).unwrap_or(false);
    if !empty && !out.join("manifest.jsonl").exists() {
        return Err(bad_input(anyhow!(
            "--out {}: is a non-empty directory without manifest.jsonl; refusing to replace it",
            out.display()
        )));
    }
    Ok(())
}

/// A directory of the dataset: a grasp record's or a sample's, with its files.
struct Entry<'a> {
    id: &'a str,
    is_grasp: bool,
    files: Vec<&'a pb::ArtifactRef>,
}

async fn write_dataset(
    store: &ArtifactStore,
    samples: &[pb::Sample],
    grasps: &[pb::GraspRecord],
    dir: &Path,
) -> Result<(usize, u64, Vec<u8>), Failure> {
    let mut entries: Vec<Entry> = Vec::with_capacity(samples.len() + grasps.len());
    for g in grasps {
        if g.grasp_id.parse::<vint_core::GraspId>().is_err() {
            return Err(anyhow!("coordinator returned a malformed grasp id {:?}", g.grasp_id).into());
        }
        entries.push(Entry { id: &g.grasp_id, is_grasp: true, files: g.file.iter().collect() });
    }
    for s in samples {
        if s.sample_id.parse::<vint_core::SampleId>().is_err() {
            return Err(anyhow!("coordinator returned a malformed sample id {:?}", s.sample_id).into());
        }
        entries.push(Entry { id: &s.sample_id, is_grasp: false, files: s.files.iter().collect() });
    }
    entries.sort_by(|a, b| a.id.cmp(b.id));
    let mut manifest = Vec::new();
    let (mut files, mut bytes) = (0usize, 0u64);
    for entry in &entries {
        let (grasp_id, sample_id) = if entry.is_grasp { (Some(entry.id), None) } else { (None, Some(entry.id)) };
        let mut line = ManifestLine { grasp_id, sample_id, files: BTreeMap::new() };
        for f in &entry.files {
            if f.name.contains('/') || f.name.starts_with('.') {
                return Err(anyhow!("{}: refusing file name {:?}", entry.id, f.name).into());
            }
            let path = dir.join(entry.id).join(&f.name);
            store.get_to_file(&f.sha256, &path).await.with_context(|| format!("{}: fetching {}", entry.id, f.name))?;
            files += 1;
            bytes += f.size;
            line.files.insert(&f.name, ManifestFile { sha256: &f.sha256, size: f.size, media_type: &f.media_type });
        }
        serde_json::to_writer(&mut manifest, &line).context("encoding manifest")?;
        manifest.push(b'\n');
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join("manifest.jsonl"), &manifest).context("writing manifest.jsonl")?;
    Ok((files, bytes, manifest))
}
