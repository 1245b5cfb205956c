//! `vintctl gc`: deletes the stored objects no job references — outputs uploaded by attempts whose
//! completion never landed (a lost lease, a crash between upload and report) — on request.
//!
//! Referenced are every task's recorded outputs (a reused task's rows name the same objects as its
//! source, so reuse keeps them alive) and every job's submitted files. Objects younger than
//! `--min-age-s` are kept whatever the database says: a worker uploads a task's outputs before it
//! completes the task, so a fresh object may belong to a completion in flight. Run it against the
//! state directory of `vintctl run`, or a cluster's database and object store.

use anyhow::Context;
use serde_json::json;
use vint_artifacts::ArtifactStore;
use vint_store::{RetryPolicy, Store};

use crate::state_dir::Records;
use crate::{CliResult, report};

pub async fn gc(records: &Records<'_>, min_age_s: u64, dry_run: bool, json: bool) -> CliResult {
    let (database, store_url) = records.urls()?;
    let store = Store::open(&database, RetryPolicy::default())
        .await
        .with_context(|| format!("opening {}", vint_telemetry::redact_url(&database)))?;
    let referenced = store.referenced_object_keys().await;
    store.close().await;
    let referenced = referenced?;
    let objects = ArtifactStore::open(&store_url)?;
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(i64::MAX);
    let min_age_ms = i64::try_from(min_age_s.saturating_mul(1_000)).unwrap_or(i64::MAX);
    let listed = objects.list_objects().await?;
    let (mut collected, mut bytes, mut young) = (0u64, 0u64, 0u64);
    for object in &listed {
        if referenced.contains(&object.key) {
            continue;
        }
        if now_ms.saturating_sub(object.modified_ms) < min_age_ms {
            young += 1;
            continue;
        }
        if !dry_run {
            objects.delete(&object.key).await?;
        }
        collected += 1;
        bytes += object.size;
    }
    let verb = if dry_run { "would delete" } else { "deleted" };
    if json {
        report::print_json(&json!({
            "objects": listed.len(), "referenced": listed.len() as u64 - collected - young,
            "collected": collected, "collected_bytes": bytes, "kept_young": young, "dry_run": dry_run,
        }));
    } else {
        println!(
            "{} objects; {verb} {collected} that no job references ({bytes} bytes); kept {young} younger than {min_age_s} s",
            listed.len()
        );
    }
    Ok(())
}
