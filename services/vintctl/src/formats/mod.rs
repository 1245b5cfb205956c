//! The dataset formats an export can write. The native layout (`export`) is the source; the
//! others are converted from a native directory: BOP's layout (`bop`), for the BOP toolkit and the
//! pose-estimation loaders built on it, WebDataset tar shards (`webdataset`), for streaming
//! training, and BOP's training-set shards (`bop_webdataset`), for the loaders of the BOP 2023
//! training sets (MegaPose's). A converter reads only the native directory and writes only its
//! output directory; the caller stages, writes the output's `manifest.jsonl` (`write_manifest`)
//! and renames it into place.

pub mod bop;
pub mod bop_webdataset;
mod ustar;
pub mod webdataset;

use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;
use sha2::{Digest, Sha256};

/// `--format`: which layout a dataset is written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One directory per sample and per grasp, models/, dataset.json, manifest.jsonl.
    Native,
    /// The BOP toolkit's layout: models/ in mm, one scene per grasp per split.
    Bop,
    /// WebDataset tar shards per split, one sample per key.
    Webdataset,
    /// BOP-webdataset: BOP's per-image members in shards per split, in a seeded order.
    BopWebdataset,
}

impl Format {
    pub fn as_str(self) -> &'static str {
        match self {
            Format::Native => "native",
            Format::Bop => "bop",
            Format::Webdataset => "webdataset",
            Format::BopWebdataset => "bop-webdataset",
        }
    }
}

/// Samples shards hold at most, by default (`--shard-samples`).
pub const SHARD_SAMPLES: u64 = 1000;

/// Where a dataset goes: its format and, for shards, how many samples each holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Target {
    pub format: Format,
    pub shard_samples: usize,
}

/// What a conversion wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Converted {
    pub samples: usize,
    pub files: usize,
    pub bytes: u64,
}

/// Converts the native dataset at `native` into `format` in the empty directory `out`.
pub fn convert(target: Target, native: &Path, out: &Path) -> anyhow::Result<Converted> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    match target.format {
        Format::Native => anyhow::bail!("a native dataset is exported, not converted"),
        Format::Bop => bop::write(native, out),
        Format::Webdataset => webdataset::write(native, out, target.shard_samples),
        Format::BopWebdataset => bop_webdataset::write(native, out, target.shard_samples),
    }
}

/// Runs `task` on every item on all cores (each thread takes every n-th item) and returns the
/// results in item order. The tasks must be independent — each writes only its own files — so
/// which thread runs one changes nothing in the bytes it writes.
pub(crate) fn on_all_cores<T: Sync, R: Send>(
    items: &[T],
    task: impl Fn(&T) -> anyhow::Result<R> + Sync,
) -> anyhow::Result<Vec<R>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, items.len().max(1));
    let task = &task;
    let done = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                scope.spawn(move || {
                    let mine = items.iter().enumerate().skip(t).step_by(threads);
                    mine.map(|(i, item)| Ok((i, task(item)?))).collect::<anyhow::Result<Vec<_>>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().map_err(|_| anyhow::anyhow!("a writer thread panicked"))?)
            .collect::<anyhow::Result<Vec<_>>>()
    })?;
    let mut results: Vec<(usize, R)> = done.into_iter().flatten().collect();
    results.sort_by_key(|(i, _)| *i);
    Ok(results.into_iter().map(|(_, r)| r).collect())
}

#[derive(Serialize)]
struct ManifestLine<'a> {
    path: &'a str,
    sha256: String,
    size: u64,
}

/// Writes `dir/manifest.jsonl`: a line `{"path", "sha256", "size"}` for every file under `dir`, in
/// path order; returns its bytes (equal outputs have equal manifests).
pub fn write_manifest(dir: &Path) -> anyhow::Result<Vec<u8>> {
    let rel = relative_files(dir)?;
    let mut manifest = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    for (path, full) in &rel {
        let mut file = std::fs::File::open(full).with_context(|| format!("reading {}", full.display()))?;
        let (mut hash, mut size) = (Sha256::new(), 0u64);
        loop {
            let n = file.read(&mut buf).with_context(|| format!("reading {}", full.display()))?;
            if n == 0 {
                break;
            }
            hash.update(&buf[..n]);
            size += n as u64;
        }
        let line = ManifestLine { path, sha256: hex::encode(hash.finalize()), size };
        serde_json::to_writer(&mut manifest, &line)?;
        manifest.push(b'\n');
    }
    std::fs::write(dir.join("manifest.jsonl"), &manifest).context("writing manifest.jsonl")?;
    Ok(manifest)
}

/// Every file under `dir` (a symbolic link counts as a file, not followed), as its path relative to
/// `dir` with `/` separators and its full path, in path order. A name that is not UTF-8 is kept,
/// lossily: none is ever passed over (`export::check_destination` must see every file).
pub fn relative_files(dir: &Path) -> anyhow::Result<Vec<(String, PathBuf)>> {
    let mut paths = Vec::new();
    collect_files(dir, &mut paths)?;
    let mut rel: Vec<(String, PathBuf)> = paths
        .into_iter()
        .map(|p| (p.strip_prefix(dir).unwrap_or(&p).to_string_lossy().replace('\\', "/"), p))
        .collect();
    rel.sort();
    Ok(rel)
}

fn collect_files(dir: &Path, out: &mut Vec<PathBuf>) -> anyhow::Result<()> {
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            collect_files(&path, out)?;
        } else {
            out.push(path);
        }
    }
    Ok(())
}
