//! `vintctl preview DIR|JOB --out SHEET.png [--samples N]`: a contact sheet that shows a native
//! dataset at a glance — per sample one row of RGB, depth, noisy depth, segmentation and the RGB
//! with the grasp's active taxels projected into it (`docs/preview.md`). The pictures are the
//! engines' Python (`python -m vint_engines preview`, which owns OpenCV and numpy); this command
//! decides what the subject is (`handover`: a job id is exported first), hands over and prints
//! the engine's summary.

use std::path::Path;

use anyhow::Context;

use crate::{CliResult, handover, report};

/// Rows when `--samples` is not given.
pub const DEFAULT_SAMPLES: u32 = 4;
/// The most rows a sheet has (the engine refuses more).
pub const MAX_SAMPLES: u32 = 64;

pub async fn run(
    subject: &str,
    out: &Path,
    samples: u32,
    store: Option<String>,
    coordinator: &vint_connect::Remote,
    json: bool,
) -> CliResult {
    let dataset = handover::dataset("preview", subject, store, coordinator).await?;
    let samples = samples.to_string();
    let done = handover::engines(
        "preview",
        &[
            "--dataset".as_ref(),
            dataset.path().as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--samples".as_ref(),
            samples.as_ref(),
            "--json".as_ref(),
        ],
    )
    .await?;
    let summary: serde_json::Value =
        serde_json::from_slice(&done.stdout).context("reading the engine's preview summary")?;
    if json {
        report::print_json(&summary);
    } else {
        let count = summary["samples"].as_array().map_or(0, Vec::len);
        let size = |i: usize| summary["size"][i].as_u64().unwrap_or_default();
        println!("{count} samples, {}×{} px: {}", size(0), size(1), out.display());
    }
    Ok(())
}
