//! The stage contracts hold by construction: every number field of the spec, at its minimum, its
//! maximum and its default, validates exactly at its bounds and yields task parameters that every
//! engine's own parser accepts (`python -m vint_engines check-params` runs the parsers the engines
//! run before they do anything; no physics, no rendering).

use std::io::Write;
use std::process::{Command, Stdio};

use serde_json::{Value, json};
use toml::Table;
use vint_core::DatasetSpec;
use vint_core::asset::Asset;
use vint_core::plan::{self, GraspChunk, JobPlan, NewTask};
use vint_core::spec::{NumberBounds, NumberField, number_fields};
use vint_tests::{python, repo_root};

/// Every modality, a built-in and a user's object, one environment of each kind (bundled by
/// name, bundled turned, a user's file) and the lens distortion's list (whose entries the fields
/// `render.distortion[i]` set one at a time): so that every number field is present and planned.
const BASE: &str = r#"
hands = ["trx3", "allegro"]
objects = ["mug", "userbox"]

[dataset]
name = "contract"
seed = 3

[object.userbox]
mesh = "assets/box.obj"
unit = "mm"
mass_kg = 0.2
material = "plastic"

[grasp]
trials_per_pair = 3
chunk_size = 2

[render]
views_per_environment = 1
environments = ["studio", { name = "forest", rotation_deg = 0.0, strength = 1.0 }, { name = "lab", file = "assets/lab.hdr" }]
distortion = [0.0, 0.0, 0.0, 0.0, 0.0]

[outputs]
modalities = ["rgb", "depth", "depth_noisy", "mask", "segmentation", "pose"]
"#;

/// The files BASE names, as the coordinator would have stored them.
fn assets() -> Vec<Asset> {
    vec![
        Asset { path: "assets/box.obj".into(), sha256: "b".repeat(64), size: 100 },
        Asset { path: "assets/lab.hdr".into(), sha256: "d".repeat(64), size: 100 },
    ]
}

fn number(field: &NumberField, which: &str) -> toml::Value {
    let scalar = match field.bounds {
        NumberBounds::Float(b) => toml::Value::Float(pick(which, b.min, b.max, b.default)),
        NumberBounds::Integer(b) => toml::Value::Integer(pick(which, b.min, b.max, b.default)),
    };
    if field.pair { toml::Value::Array(vec![scalar.clone(), scalar]) } else { scalar }
}

fn pick<T>(which: &str, min: T, max: T, default: T) -> T {
    match which {
        "min" => min,
        "max" => max,
        _ => default,
    }
}

/// BASE with `field` set to `value` (every entry for `[*]`, the spec's own object for `*`).
fn with_value(field: &NumberField, value: toml::Value) -> String {
    let mut root: Table = BASE.parse().expect("BASE is TOML");
    let path = field.path.replace(".*.", ".userbox.");
    set(&mut root, &path.split('.').collect::<Vec<_>>(), &value);
    toml::to_string(&root).expect("TOML serializes")
}

fn set(table: &mut Table, path: &[&str], value: &toml::Value) {
    let (head, rest) = path.split_first().expect("non-empty path");
    if rest.is_empty() {
        // `name[i]`: one entry of a list BASE writes out.
        if let Some((list, index)) = head.strip_suffix(']').and_then(|h| h.split_once('['))
            && let Ok(index) = index.parse::<usize>()
        {
            let Some(toml::Value::Array(items)) = table.get_mut(list) else { panic!("{list} is not a list") };
            items[index] = value.clone();
            return;
        }
        table.insert(head.to_string(), value.clone());
        return;
    }
    if let Some(list) = head.strip_suffix("[*]") {
        let Some(toml::Value::Array(items)) = table.get_mut(list) else { panic!("{list} is not a list") };
        for item in items.iter_mut() {
            if let toml::Value::Table(t) = item {
                set(t, rest, value);
            }
        }
        return;
    }
    let entry = table.entry(head.to_string()).or_insert_with(|| toml::Value::Table(Table::new()));
    let toml::Value::Table(t) = entry else { panic!("{head} is not a table") };
    set(t, rest, value);
}

/// A value just outside a bound, or `None` where there is no such TOML value.
fn beyond(field: &NumberField, which: &str) -> Option<toml::Value> {
    let scalar = match field.bounds {
        NumberBounds::Float(b) => {
            let x = if which == "min" { b.min } else { b.max };
            let step = x.abs().max(1.0) * 1e-6;
            toml::Value::Float(if which == "min" { x - step } else { x + step })
        }
        NumberBounds::Integer(b) => {
            let x = if which == "min" { b.min.checked_sub(1) } else { b.max.checked_add(1) };
            toml::Value::Integer(x?)
        }
    };
    Some(if field.pair { toml::Value::Array(vec![scalar.clone(), scalar]) } else { scalar })
}

/// The path an error about `field` carries (`render.environments[0].strength`, `object.userbox.mass_kg`).
fn reported_under(error_path: &str, field: &NumberField) -> bool {
    let pattern = field.path.replace(".*.", ".userbox.");
    let mut rest = error_path;
    for (i, part) in pattern.split("[*]").enumerate() {
        if i > 0 {
            let Some(close) = rest.strip_prefix('[').and_then(|r| r.find(']').map(|n| &r[n + 1..])) else {
                return false;
            };
            rest = close;
        }
        let Some(after) = rest.strip_prefix(part) else { return false };
        rest = after;
    }
    rest.is_empty() || rest.starts_with('[')
}

#[test]
fn every_number_field_is_accepted_at_its_bounds_and_refused_beyond_them() {
    for field in number_fields() {
        for which in ["min", "max", "default"] {
            let text = with_value(&field, number(&field, which));
            if let Err(errors) = DatasetSpec::parse(&text) {
                // Rules across fields may refuse an extreme (views × environments ≤ 100); the
                // field's own range must not.
                let own: Vec<_> =
                    errors.0.iter().filter(|e| reported_under(&e.path, &field) && is_range_rule(&e.rule)).collect();
                assert!(own.is_empty(), "{} at its {which} is refused: {own:?}", field.path);
            }
            if which == "default" {
                continue;
            }
            if let Some(value) = beyond(&field, which) {
                let errors = DatasetSpec::parse(&with_value(&field, value.clone())).expect_err(field.path);
                assert!(
                    errors.0.iter().any(|e| reported_under(&e.path, &field) && is_range_rule(&e.rule)),
                    "{} = {value} beyond its {which} is not reported under its path: {errors}",
                    field.path
                );
            }
        }
    }
}

/// The wording of the reader's range rules (`must be in [0, 30]`, `must be 1..=1024`).
fn is_range_rule(rule: &str) -> bool {
    rule.starts_with("must be in [") || (rule.starts_with("must be ") && rule.contains("..="))
}

#[test]
fn every_number_field_of_the_spec_is_listed() {
    // A spec with every section: its number leaves, as the reader keeps them, must each be a field
    // of `number_fields` (a field the list misses would escape the tests in this file).
    let spec = DatasetSpec::parse(BASE).expect("BASE validates");
    let mut leaves = Vec::new();
    number_leaves(&serde_json::to_value(&spec).expect("spec serializes"), String::new(), &mut leaves);
    let listed: Vec<&str> = number_fields().iter().map(|f| f.path).collect();
    for leaf in leaves {
        let path = leaf
            .replace("object_defs.userbox.", "object.*.")
            .replace("render.environments[0].", "render.environments[*].")
            .replace("render.environments[1].", "render.environments[*].")
            .replace("render.environments[2].", "render.environments[*].");
        // A pair's two entries share their field; a list with bounds per entry lists each.
        let pair = path.trim_end_matches("[0]").trim_end_matches("[1]");
        assert!(listed.contains(&path.as_str()) || listed.contains(&pair), "{leaf} is not in spec::number_fields");
    }
}

fn number_leaves(v: &Value, path: String, out: &mut Vec<String>) {
    let join = |key: &str| if path.is_empty() { key.to_string() } else { format!("{path}.{key}") };
    match v {
        Value::Number(_) => out.push(path),
        Value::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                number_leaves(item, format!("{path}[{i}]"), out);
            }
        }
        Value::Object(map) => {
            for (key, value) in map {
                number_leaves(value, join(key), out);
            }
        }
        _ => {}
    }
}

/// The tasks a job of `spec` would run first: every (object, hand) pair's first grasp chunk, and
/// what that chunk unlocks when every trial is accepted.
fn planned(spec: &DatasetSpec) -> Vec<NewTask> {
    let assets = assets();
    let job = JobPlan::new(spec, &assets).expect("plans");
    let mut tasks = Vec::new();
    for object in &spec.objects {
        for hand in &spec.hands {
            let chunk = GraspChunk { object: object.clone(), hand: hand.clone(), chunk: 0 };
            tasks.push(plan::grasp_task(spec, &job, &chunk, &assets).expect("grasp task"));
            let accepted: Vec<u32> = job.trials(&chunk).collect();
            let unlocked = plan::after_grasp(&job, &chunk, &accepted).expect("children");
            // One of each stage: the others differ only in seeds and indices.
            for stage in vint_core::Stage::ALL {
                tasks.extend(unlocked.iter().find(|t| t.stage == stage).cloned());
            }
        }
    }
    tasks
}

/// Each task's verdict from the engines' own parsers.
fn engine_verdicts(tasks: &[(String, NewTask)]) -> Vec<Value> {
    let input: Vec<Value> = tasks.iter().map(|(_, t)| json!({"stage": t.stage.as_str(), "params": t.params})).collect();
    let mut child = Command::new(python())
        .args(["-m", "vint_engines", "check-params"])
        .env("PYTHONPATH", repo_root().join("workers/engines"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the engines' parameter check");
    let mut stdin = child.stdin.take().expect("stdin");
    let body = serde_json::to_vec(&input).expect("JSON");
    let writer = std::thread::spawn(move || stdin.write_all(&body));
    let output = child.wait_with_output().expect("check-params runs");
    writer.join().expect("writer thread").expect("write the tasks");
    assert!(output.status.success(), "check-params failed: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("check-params answers JSON")
}

#[test]
fn a_spec_at_any_bound_yields_parameters_every_engine_accepts() {
    let mut tasks: Vec<(String, NewTask)> = Vec::new();
    let mut specs = 0;
    for field in number_fields() {
        for which in ["min", "max", "default"] {
            // Specs that break a rule across fields (render.radius_m at its minimum stands the camera
            // inside the noise mode's minimum range) do not validate, so no task is ever planned
            // from them.
            let Ok(spec) = DatasetSpec::parse(&with_value(&field, number(&field, which))) else {
                continue;
            };
            specs += 1;
            for task in planned(&spec) {
                tasks.push((format!("{} at its {which}: {} task {}", field.path, task.stage, task.key), task));
            }
        }
    }
    // Besides the rules above, k1, k2 and k3 at their minimum (the strongest barrel) fold the lens
    // back inside BASE's image, which the spec refuses (`render.distortion`).
    assert!(specs >= 3 * number_fields().len() - 13, "only {specs} specs validated");
    let verdicts = engine_verdicts(&tasks);
    assert_eq!(verdicts.len(), tasks.len());
    let refused: Vec<String> = tasks
        .iter()
        .zip(&verdicts)
        .filter(|(_, v)| v["ok"] != true)
        .map(|((what, _), v)| format!("{what}: {}", v["error"]))
        .collect();
    assert!(refused.is_empty(), "{} of {} planned tasks refused:\n{}", refused.len(), tasks.len(), refused.join("\n"));
    // Every stage was checked.
    for stage in vint_core::Stage::ALL {
        assert!(tasks.iter().any(|(_, t)| t.stage == stage), "no {stage} task was planned");
    }
}

#[test]
fn the_engines_refuse_what_the_contract_refuses() {
    // The check above can only fail if the parsers refuse things: prove they do, for each stage.
    let spec = DatasetSpec::parse(BASE).expect("BASE validates");
    let mut tasks: Vec<(String, NewTask)> = Vec::new();
    for mut task in planned(&spec) {
        let broken = match task.stage {
            vint_core::Stage::Grasp => ("/physics/hold_s", json!(45.0)),
            vint_core::Stage::Render => ("/render/fov_deg", json!(160.0)),
            vint_core::Stage::Noise => ("/noise/flying_invalid_share", json!(1.5)),
            vint_core::Stage::Package => ("/modalities/0", json!("normals")),
        };
        *task.params.pointer_mut(broken.0).expect("the field exists") = broken.1;
        tasks.push((broken.0.to_string(), task));
    }
    for ((field, task), verdict) in tasks.iter().zip(engine_verdicts(&tasks)) {
        assert_eq!(verdict["ok"], false, "{} accepted {field} out of bounds", task.stage);
        let path = format!("params{}", field.replace('/', ".")).replace(".0", "[0]");
        assert!(verdict["error"].as_str().unwrap_or_default().contains(&path), "{}: {verdict}", task.stage);
    }
}
