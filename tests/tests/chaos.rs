//! The short chaos run: one round of `benches/chaos.py` (workers and engines SIGKILLed, the
//! coordinator killed and restarted, Postgres restarted, S3 errors, delays and dropped connections,
//! at seeded random moments during a tiny job) must end with the embedded run's manifest, byte for
//! byte, and a bucket holding exactly the job's lineage. The full 20-round run and its tally are in
//! docs/benchmarks.md.
//!
//! It needs the PostgreSQL server binaries (initdb, pg_ctl: the run owns and restarts its own
//! cluster) and moto_server from the engines' venv; without them the run fails, it is not skipped.

use std::process::Command;

use vint_tests::*;

#[test]
fn a_short_chaos_run_ends_identical() {
    let work = tempfile::tempdir().unwrap();
    let tally = work.path().join("chaos.jsonl");
    let bin_dir = bin("vintctl").parent().expect("the binaries' directory").to_path_buf();
    bin("vint-coordinator");
    bin("vint-worker");
    let o = Command::new(python())
        .arg(repo_root().join("benches/chaos.py"))
        .args(["--rounds", "1", "--seed", "12", "--workers", "3", "--gap-s", "3", "--budget-s", "420"])
        .arg("--bin-dir")
        .arg(&bin_dir)
        .arg("--out")
        .arg(&tally)
        .arg("--work-dir")
        .arg(work.path())
        .output()
        .expect("run benches/chaos.py");
    let log = stderr(&o);
    let tail = &log[log.len().saturating_sub(8_000)..];
    assert!(o.status.success(), "the chaos run failed (logs under {}):\n{tail}", work.path().display());

    let rounds: Vec<serde_json::Value> = std::fs::read_to_string(&tally)
        .expect("the tally")
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    assert_eq!(rounds.len(), 1, "{rounds:?}");
    let round = &rounds[0];
    assert_eq!(round["job_state"], "succeeded", "{round:#}");
    assert_eq!(round["identical"], true, "{round:#}");
    assert_eq!(round["orphan_objects"], 0, "{round:#}");
    assert_eq!(round["missing_objects"], 0, "{round:#}");
    assert!(round["samples"].as_u64().unwrap_or(0) > 0, "{round:#}");
    let faults: u64 = round["faults"].as_object().expect("faults").values().filter_map(|v| v.as_u64()).sum();
    assert!(faults >= 2, "chaos must have happened: {round:#}\n{tail}");
}
