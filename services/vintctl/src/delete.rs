//! `vintctl delete JOB`: removes an ended job and every row of it from the database, from a
//! `vintctl run` state directory or a cluster's database. Its objects stay until `vintctl gc`
//! finds them referenced by no job (another job may hold the same content, and reuse shares it).

use anyhow::{Context, anyhow};
use serde_json::json;
use vint_store::{RetryPolicy, Store, StoreError};

use crate::failure::bad_input;
use crate::state_dir::Records;
use crate::{CliResult, report};

pub async fn delete(records: &Records<'_>, job: &str, dry_run: bool, json: bool) -> CliResult {
    let (database, _) = records.urls()?;
    let store = Store::open(&database, RetryPolicy::default())
        .await
        .with_context(|| format!("opening {}", vint_telemetry::redact_url(&database)))?;
    let deleted = store.delete_job(job, dry_run).await;
    store.close().await;
    let deleted = match deleted {
        Ok(deleted) => deleted,
        Err(e @ (StoreError::NotFound(_) | StoreError::Invalid(_))) => {
            return Err(bad_input(anyhow!("job {job:?}: {e}")));
        }
        Err(e) => return Err(anyhow::Error::from(e).context(format!("deleting job {job}")).into()),
    };
    let verb = if dry_run { "would delete" } else { "deleted" };
    if json {
        report::print_json(&json!({
            "job": job, "dry_run": dry_run, "tasks": deleted.tasks, "attempts": deleted.attempts,
            "outputs": deleted.outputs, "submitted_files": deleted.assets,
        }));
    } else {
        println!(
            "job {job}: {verb} {} tasks, {} attempts, {} output records, {} submitted files' records; \
             `vintctl gc` then deletes the objects no job references any more",
            deleted.tasks, deleted.attempts, deleted.outputs, deleted.assets
        );
    }
    Ok(())
}
