//! `vintctl eval --dataset DIR --estimates FILE`: scores pose estimates (BOP results CSV) against a
//! BOP dataset's ground truth with ADD, ADD-S and ADD(S) — their AUC up to 10 cm and the share
//! within 0.1 and 0.05 of the object's diameter — overall, per object and per occlusion bucket
//! (the layout of the VinT-6D paper's Tables 3–6). docs/metrics.md defines every number.
//!
//! Every ground-truth instance counts once: the best-scored estimate of its (scene, image, object)
//! is its estimate, and an instance with none has an infinite error (it fails every threshold but
//! stays in every denominator). Reads the dataset and the CSV; writes nothing.

mod dataset;
mod estimates;
mod kdtree;
mod metrics;
pub(crate) mod ply;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use serde_json::{Value, json};

use crate::report::print_json;
use crate::{CliResult, bad_input};
use dataset::{Dataset, Instance, Model};
use estimates::Estimate;
use metrics::AUC_MAX_MM;

/// What to score against what.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// The BOP dataset (`vintctl run … --format bop`): models_eval/ (else models/) with
    /// models_info.json and obj_NNNNNN.ply, and <split>/<scene_id>/scene_gt.json and
    /// scene_gt_info.json.
    #[arg(long)]
    pub dataset: PathBuf,
    /// The estimates: a BOP results CSV (`scene_id,im_id,obj_id,score,R,t,time`; R row-major, t in
    /// mm).
    #[arg(long)]
    pub estimates: PathBuf,
    /// Score only this split (train, val, test; repeat for several). Default: every split the
    /// dataset has.
    #[arg(long = "split", value_name = "NAME")]
    pub splits: Vec<String>,
}

/// Occlusion buckets: 10 % wide, as the paper's Table 6 steps occlusion.
const BUCKETS: usize = 10;

/// The shares of the diameter the success rates use (ADD(S)-0.1d, ADD(S)-0.05d).
const WITHIN: [(f64, &str); 2] = [(0.1, "0.1d"), (0.05, "0.05d")];

pub fn run(args: &EvalArgs, json: bool) -> CliResult {
    let dataset = dataset::read(&args.dataset, &args.splits)
        .map_err(|e| bad_input(e.context(format!("eval: dataset {}", args.dataset.display()))))?;
    let text = std::fs::read_to_string(&args.estimates)
        .with_context(|| format!("eval: reading estimates {}", args.estimates.display()))
        .map_err(bad_input)?;
    let estimates = estimates::parse(&text)
        .map_err(|e| bad_input(anyhow::Error::new(e).context(format!("eval: {}", args.estimates.display()))))?;
    let scoring = score(&dataset, &estimates);
    let report = Report { args, dataset: &dataset, scoring: &scoring, rows: estimates.len() };
    if json {
        print_json(&report.json());
    } else {
        print!("{}", report.text());
    }
    Ok(())
}

/// One ground-truth instance and the estimate it was scored with.
struct Scored<'a> {
    instance: &'a Instance,
    model: &'a Model,
    estimate: Option<&'a Estimate>,
    /// Infinite without an estimate.
    add: f64,
    adds: f64,
}

impl Scored<'_> {
    /// ADD(S): ADD-S for a symmetric object, ADD otherwise.
    fn add_s(&self) -> f64 {
        if self.model.symmetric { self.adds } else { self.add }
    }

    fn occlusion(&self) -> f64 {
        1.0 - self.instance.visib_fract
    }

    fn bucket(&self) -> usize {
        bucket(self.occlusion())
    }
}

/// Bucket k holds occlusion in [k/10, (k+1)/10); full occlusion joins the last. The 1e-9 keeps a
/// visib_fract of 0.8 (occlusion 0.19999999999999996 in floating point) in the 20 % bucket.
fn bucket(occlusion: f64) -> usize {
    ((occlusion * BUCKETS as f64 + 1e-9).floor().max(0.0) as usize).min(BUCKETS - 1)
}

struct Scoring<'a> {
    /// One per ground-truth instance, in the dataset's order.
    scored: Vec<Scored<'a>>,
    /// Estimates of an image and object below the best-scored one (lower or equal score, later
    /// line), which are not scored.
    duplicates: usize,
    /// Estimates of an image or object the selected splits do not annotate.
    unmatched: usize,
}

/// Pairs every instance with its estimate and measures the errors.
fn score<'a>(dataset: &'a Dataset, estimates: &'a [Estimate]) -> Scoring<'a> {
    type Key = (u32, u32, u32);
    let mut by_key: BTreeMap<Key, Vec<&Estimate>> = BTreeMap::new();
    for e in estimates {
        by_key.entry((e.scene_id, e.im_id, e.obj_id)).or_default().push(e);
    }
    let mut instances_by_key: BTreeMap<Key, Vec<&Instance>> = BTreeMap::new();
    for i in &dataset.instances {
        instances_by_key.entry((i.scene_id, i.im_id, i.obj_id)).or_default().push(i);
    }
    let unmatched = by_key.iter().filter(|(k, _)| !instances_by_key.contains_key(k)).map(|(_, v)| v.len()).sum();
    let mut duplicates = 0;
    let mut scored = Vec::with_capacity(dataset.instances.len());
    for (key, instances) in &instances_by_key {
        let mut candidates = by_key.remove(key).unwrap_or_default();
        // Best score first; equal scores keep file order (a stable sort).
        candidates.sort_by(|a, b| b.score.total_cmp(&a.score));
        let model = &dataset.models[&key.2];
        let mut open: Vec<&Instance> = instances.clone();
        for estimate in candidates {
            if open.is_empty() {
                duplicates += 1;
                continue;
            }
            // Several instances of one object in an image: the estimate takes the one it fits
            // best (by ADD(S)), as BOP matches greedily in score order. vint images hold one.
            let mut best: Option<(usize, Scored)> = None;
            for (k, instance) in open.iter().enumerate() {
                let s = Scored {
                    instance,
                    model,
                    estimate: Some(estimate),
                    add: metrics::add(&model.points, &estimate.pose, &instance.pose),
                    adds: metrics::adds(&model.points, &estimate.pose, &instance.pose),
                };
                if best.as_ref().is_none_or(|(_, b)| s.add_s() < b.add_s()) {
                    best = Some((k, s));
                }
            }
            if let Some((k, s)) = best {
                open.remove(k);
                scored.push(s);
            }
        }
        for instance in open {
            scored.push(Scored { instance, model, estimate: None, add: f64::INFINITY, adds: f64::INFINITY });
        }
    }
    scored.sort_by_key(|s| (s.instance.scene_id, s.instance.im_id, s.instance.gt_index));
    Scoring { scored, duplicates, unmatched }
}

/// The scores of a group of instances (all, one object, one occlusion bucket); `None` when the
/// group is empty.
struct Metrics {
    n: usize,
    estimated: usize,
    add_auc: Option<f64>,
    adds_auc: Option<f64>,
    add_s_auc: Option<f64>,
    add_s_within: [Option<f64>; 2],
}

impl Metrics {
    fn of<'s>(group: impl Iterator<Item = &'s Scored<'s>>) -> Metrics {
        let group: Vec<&Scored> = group.collect();
        let errors = |f: fn(&Scored) -> f64| group.iter().map(|s| f(s)).collect::<Vec<f64>>();
        let with_diameter: Vec<(f64, f64)> = group.iter().map(|s| (s.add_s(), s.model.diameter_mm)).collect();
        Metrics {
            n: group.len(),
            estimated: group.iter().filter(|s| s.estimate.is_some()).count(),
            add_auc: metrics::auc(&errors(|s| s.add), AUC_MAX_MM),
            adds_auc: metrics::auc(&errors(|s| s.adds), AUC_MAX_MM),
            add_s_auc: metrics::auc(&errors(|s| s.add_s()), AUC_MAX_MM),
            add_s_within: WITHIN.map(|(fraction, _)| metrics::within_percent(&with_diameter, fraction)),
        }
    }

    fn json(&self) -> Value {
        let mut v = json!({
            "n": self.n, "estimated": self.estimated, "missing": self.n - self.estimated,
            "add_auc": self.add_auc, "adds_auc": self.adds_auc, "add_s_auc": self.add_s_auc,
        });
        for ((_, label), value) in WITHIN.iter().zip(self.add_s_within) {
            v[format!("add_s_{label}")] = json!(value);
        }
        v
    }
}

/// A finite error as JSON; a missing estimate's infinite one as null.
fn mm(e: f64) -> Value {
    if e.is_finite() { json!(e) } else { Value::Null }
}

struct Report<'a> {
    args: &'a EvalArgs,
    dataset: &'a Dataset,
    scoring: &'a Scoring<'a>,
    rows: usize,
}

impl Report<'_> {
    fn overall(&self) -> Metrics {
        Metrics::of(self.scoring.scored.iter())
    }

    fn per_object(&self) -> Vec<(&Model, Metrics)> {
        let scored = &self.scoring.scored;
        let of = |m: &Model| Metrics::of(scored.iter().filter(move |s| s.model.obj_id == m.obj_id));
        self.dataset.models.values().map(|m| (m, of(m))).collect()
    }

    fn per_bucket(&self) -> Vec<Metrics> {
        (0..BUCKETS).map(|b| Metrics::of(self.scoring.scored.iter().filter(move |s| s.bucket() == b))).collect()
    }

    fn json(&self) -> Value {
        let objects: Vec<Value> = self
            .per_object()
            .into_iter()
            .map(|(m, metrics)| {
                let mut v = json!({"obj_id": m.obj_id, "name": m.name, "symmetric": m.symmetric,
                                   "diameter_mm": m.diameter_mm, "points": m.points.len()});
                merge(&mut v, metrics.json());
                v
            })
            .collect();
        let buckets: Vec<Value> = self
            .per_bucket()
            .into_iter()
            .enumerate()
            .map(|(b, metrics)| {
                let mut v = json!({"bucket": bucket_label(b), "occlusion_min": b as f64 / BUCKETS as f64,
                                   "occlusion_max": (b + 1) as f64 / BUCKETS as f64});
                merge(&mut v, metrics.json());
                v
            })
            .collect();
        let per_estimate: Vec<Value> = self.scoring.scored.iter().map(per_estimate_json).collect();
        json!({
            "dataset": self.args.dataset, "estimates_file": self.args.estimates, "splits": self.dataset.splits,
            "auc_max_mm": AUC_MAX_MM,
            "models": self.dataset.models_dir,
            "estimates": {"rows": self.rows, "used": self.scoring.scored.iter().filter(|s| s.estimate.is_some()).count(),
                          "duplicates": self.scoring.duplicates, "unmatched": self.scoring.unmatched},
            "overall": self.overall().json(),
            "objects": objects,
            "occlusion": buckets,
            "per_estimate": per_estimate,
        })
    }

    fn text(&self) -> String {
        let mut out = String::new();
        let overall = self.overall();
        let s = self.scoring;
        let _ = writeln!(out, "# Pose accuracy: {}", self.args.estimates.display());
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "Dataset {} (splits {}): {} ground-truth instances, {} with an estimate, {} missing (scored as failures).",
            self.args.dataset.display(),
            self.dataset.splits.join(", "),
            overall.n,
            overall.estimated,
            overall.n - overall.estimated
        );
        let _ = writeln!(
            out,
            "Estimates: {} rows; not scored: {} below the best of their image and object, {} for images or objects \
             without ground truth.",
            self.rows, s.duplicates, s.unmatched
        );
        let _ = writeln!(out, "{}", points_note(self.dataset.models_dir));
        let _ = writeln!(
            out,
            "AUC: area under accuracy over thresholds 0–{AUC_MAX_MM} mm, ×100 (YCB-Video toolbox, as PoseCNN and PVN3D). \
             ADD(S): ADD-S for symmetric objects, ADD otherwise; -0.1d, -0.05d: % of instances with ADD(S) below \
             that share of the diameter. See docs/metrics.md."
        );
        let _ = writeln!(out);
        let _ = writeln!(out, "## Per object");
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "| object | obj_id | symmetric | n | ADD AUC | ADD-S AUC | ADD(S) AUC | ADD(S)-0.1d | ADD(S)-0.05d |"
        );
        let _ = writeln!(out, "|---|---:|:-:|---:|---:|---:|---:|---:|---:|");
        let row = |out: &mut String, name: &str, id: &str, sym: &str, m: &Metrics| {
            let _ = writeln!(
                out,
                "| {name} | {id} | {sym} | {} | {} | {} | {} | {} | {} |",
                m.n,
                cell(m.add_auc),
                cell(m.adds_auc),
                cell(m.add_s_auc),
                cell(m.add_s_within[0]),
                cell(m.add_s_within[1])
            );
        };
        for (model, metrics) in self.per_object() {
            let sym = if model.symmetric { "yes" } else { "no" };
            row(&mut out, &model.name, &model.obj_id.to_string(), sym, &metrics);
        }
        row(&mut out, "**all**", "", "", &overall);
        let _ = writeln!(out);
        let _ = writeln!(out, "## By occlusion (1 − visib_fract)");
        let _ = writeln!(out);
        let buckets = self.per_bucket();
        let shown: Vec<usize> = (0..BUCKETS).filter(|b| buckets[*b].n > 0).collect();
        let _ = write!(out, "| occlusion |");
        for b in &shown {
            let _ = write!(out, " {} |", bucket_label(*b));
        }
        let _ = writeln!(out);
        let _ = writeln!(out, "|---|{}", "---:|".repeat(shown.len()));
        let lines: [(&str, Cell); 6] = [
            ("n", |m| m.n.to_string()),
            ("ADD(S) AUC", |m| cell(m.add_s_auc)),
            ("ADD(S)-0.1d", |m| cell(m.add_s_within[0])),
            ("ADD(S)-0.05d", |m| cell(m.add_s_within[1])),
            ("ADD AUC", |m| cell(m.add_auc)),
            ("ADD-S AUC", |m| cell(m.adds_auc)),
        ];
        for (name, value) in lines {
            let _ = write!(out, "| {name} |");
            for b in &shown {
                let _ = write!(out, " {} |", value(&buckets[*b]));
            }
            let _ = writeln!(out);
        }
        out
    }
}

/// What the errors were measured on.
fn points_note(models_dir: &str) -> String {
    if models_dir == "models_eval" {
        "Points: the vertices of models_eval/ (each model resampled uniformly over its surface, what the BOP \
         toolkit scores on)."
            .to_string()
    } else {
        format!(
            "Points: the vertices of {models_dir}/ — this dataset has no models_eval/, and a model's vertices need not \
             lie uniformly over its surface, so these numbers are not comparable with published ones."
        )
    }
}

/// How one row of the occlusion table reads a group's metrics.
type Cell = fn(&Metrics) -> String;

fn per_estimate_json(s: &Scored) -> Value {
    let i = s.instance;
    let within: Vec<(String, Value)> = WITHIN
        .iter()
        .map(|(fraction, label)| (format!("add_s_{label}"), json!(s.add_s() < fraction * s.model.diameter_mm)))
        .collect();
    let mut v = json!({
        "split": i.split, "scene_id": i.scene_id, "im_id": i.im_id, "gt_index": i.gt_index, "obj_id": i.obj_id,
        "symmetric": s.model.symmetric, "occlusion": s.occlusion(), "occlusion_bucket": bucket_label(s.bucket()),
        "estimated": s.estimate.is_some(), "line": s.estimate.map(|e| e.line), "score": s.estimate.map(|e| e.score),
        "add_mm": mm(s.add), "adds_mm": mm(s.adds), "add_s_mm": mm(s.add_s()),
    });
    for (k, value) in within {
        v[k] = value;
    }
    v
}

fn merge(into: &mut Value, from: Value) {
    if let (Value::Object(into), Value::Object(from)) = (into, from) {
        into.extend(from);
    }
}

fn bucket_label(b: usize) -> String {
    format!("{}–{} %", b * 100 / BUCKETS, (b + 1) * 100 / BUCKETS)
}

/// A percentage with two decimals, as the paper prints them; "–" for an empty group.
fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "–".to_string(), |v| format!("{v:.2}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occlusion_buckets_are_ten_percent_wide_and_round_tenths_up() {
        assert_eq!(bucket(0.0), 0);
        assert_eq!(bucket(0.0999), 0);
        assert_eq!(bucket(1.0 - 0.8), 2); // 0.19999999999999996
        assert_eq!(bucket(1.0 - 0.7), 3); // 0.30000000000000004
        assert_eq!(bucket(0.95), 9);
        assert_eq!(bucket(1.0), 9);
        assert_eq!(bucket_label(2), "20–30 %");
    }
}
