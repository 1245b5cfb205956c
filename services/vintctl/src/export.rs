//! Writing a job's packaged samples to a directory: one directory per sample and a
//! `manifest.jsonl` listing every file with its SHA-256.
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
    sample_id: &'a str,
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
    let written = write_dataset(store, samples, &staging).await;
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

async fn write_dataset(
    store: &ArtifactStore,
    samples: &[pb::Sample],
    dir: &Path,
) -> Result<(usize, u64, Vec<u8>), Failure> {
    let mut manifest = Vec::new();
    let (mut files, mut bytes) = (0usize, 0u64);
    let mut sorted: Vec<&pb::Sample> = samples.iter().collect();
    sorted.sort_by(|a, b| a.sample_id.cmp(&b.sample_id));
    for sample in sorted {
        if sample.sample_id.parse::<vint_core::SampleId>().is_err() {
            return Err(anyhow!("coordinator returned a malformed sample id {:?}", sample.sample_id).into());
        }
        let mut line = ManifestLine { sample_id: &sample.sample_id, files: BTreeMap::new() };
        for f in &sample.files {
            if f.name.contains('/') || f.name.starts_with('.') {
                return Err(anyhow!("sample {}: refusing file name {:?}", sample.sample_id, f.name).into());
            }
            let path = dir.join(&sample.sample_id).join(&f.name);
            store
                .get_to_file(&f.sha256, &path)
                .await
                .with_context(|| format!("sample {}: fetching {}", sample.sample_id, f.name))?;
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
