//! `vintctl plan SPEC --against JOB`: per stage, how many of the spec's tasks a run would reuse
//! from the store's finished results and why the others would run (`vint_coordinator::forecast`).
//!
//! It reads the state directory `vintctl run` keeps (its SQLite database), or a cluster's database
//! (`--database`), and keys tasks with the engines of this machine: the Python engines' identities (`python -m vint_engines identity`)
//! and the package stage's format.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Context, anyhow};
use serde_json::json;
use sha2::{Digest, Sha256};
use vint_coordinator::forecast::{self, Forecast};
use vint_core::Stage;
use vint_core::asset::Asset;
use vint_store::{RetryPolicy, Store};

use crate::spec_file::{LoadedSpec, load_spec};
use crate::state_dir::Records;
use crate::{CliResult, bad_input, handover, report};

pub async fn plan_against(spec_path: &Path, job: &str, records: &Records<'_>, json: bool) -> CliResult {
    let LoadedSpec { spec, assets, .. } = load_spec(spec_path)?;
    let (url, _) = records.urls()?;
    let assets: Vec<Asset> = assets
        .iter()
        .map(|a| Asset {
            path: a.path.clone(),
            sha256: hex::encode(Sha256::digest(&a.content)),
            size: a.content.len() as u64,
        })
        .collect();
    let identities = identities(json).await;
    let store = Store::open(&url, RetryPolicy::default())
        .await
        .with_context(|| format!("opening {}", vint_telemetry::redact_url(&url)))?;
    let result = forecast::forecast(&store, &spec, &assets, &identities, job).await;
    store.close().await;
    let f = match result {
        Ok(f) => f,
        Err(e @ forecast::ForecastError::NoJob(_)) => return Err(bad_input(anyhow!("--against: {e}"))),
        Err(e) => return Err(anyhow!(e).into()),
    };
    if json {
        report::print_json(&json!(f));
    } else {
        print!("{}", text(&f));
    }
    Ok(())
}

/// This machine's engine identities; a stage whose identity cannot be read is forecast to run.
async fn identities(quiet: bool) -> HashMap<Stage, String> {
    let mut out = HashMap::from([(Stage::Package, vint_core::contract::package::ENGINE_IDENTITY.to_string())]);
    match handover::engines("identity", &[]).await {
        Ok(done) => match vint_core::reuse::parse_identities(&done.stdout) {
            Ok(ids) => out.extend(ids),
            Err(e) if !quiet => {
                eprintln!("warning: the engines' identities could not be read ({e}): their tasks are forecast to run")
            }
            Err(_) => {}
        },
        Err(f) if !quiet => eprintln!(
            "warning: the engines' identities are unknown here ({}): their tasks are forecast to run",
            f.error
        ),
        Err(_) => {}
    }
    out
}

/// The forecast as a table, one line per stage, then the reasons.
pub fn text(f: &Forecast) -> String {
    let mut out = format!("against job {}:\n", f.against);
    out.push_str(&format!("  {:<8} {:>8} {:>8} {:>8}  why they run\n", "stage", "planned", "reused", "run"));
    for stage in Stage::ALL {
        let Some(s) = f.stages.get(stage.as_str()) else { continue };
        let mut reasons: Vec<(&String, &u64)> = s.reasons.iter().collect();
        reasons.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
        let why: Vec<String> = reasons.iter().map(|(r, n)| format!("{r} ({n})")).collect();
        out.push_str(&format!(
            "  {:<8} {:>8} {:>8} {:>8}  {}\n",
            stage.as_str(),
            s.planned,
            s.reused,
            s.run,
            why.join("; ")
        ));
        if s.after_runs > 0 {
            out.push_str(&format!(
                "  {:<8} + planned when their grasp chunks finish ({} in that job)\n",
                "", s.after_runs
            ));
        }
    }
    out
}
