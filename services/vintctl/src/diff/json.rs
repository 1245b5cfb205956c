//! JSON documents (a sample's `meta.json`, a grasp's record, any other `.json`): both are walked
//! together; numbers are compared by what they measure, and any difference of structure (a key or
//! an array element present on one side only, another type, another string) is a difference.
//!
//! What a number measures is read from its key, or the nearest enclosing key that says:
//! - lengths in metres — positions and translations (`p`, `t_w2c`, `t_m2c`, `p_palm`) and every
//!   key ending `_m` — absolute, `position_m`;
//! - orientations, unitless — quaternions `q`, rotation matrices `R_w2c`/`R_m2c`, unit normals
//!   (`n_palm`, `normal`) and angles in radians (`joints`, `azimuth`) — absolute, `rotation`;
//! - touch readings (`reading`, `readings`) — absolute, `touch`;
//! - integers (seeds, indices, taxel numbers, step and taxel counts) — exactly, except pixel counts
//!   (`*_px`), which follow the next rule as the label images they count follow `label_share`;
//! - everything else (forces, speeds, energies, ratios such as `occlusion`, camera intrinsics) —
//!   `relative` to the larger magnitude, or absolutely for numbers below 1 (as numpy's `isclose`
//!   combines a relative and an absolute tolerance), so that a share near 0 is not judged by a
//!   ratio of two tiny numbers.

use serde_json::Value;

use super::{Finding, Measure, Tolerances};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Quantity {
    Length,
    Orientation,
    Touch,
    Other,
}

/// At most this many structural differences are listed per document.
const NOTES: usize = 10;

pub fn compare(a: &Value, b: &Value, tolerances: &Tolerances) -> Finding {
    let mut walk = Walk { tolerances, worst: Vec::new(), notes: Vec::new(), more_notes: 0 };
    walk.visit(a, b, &mut Vec::new());
    if walk.more_notes > 0 {
        walk.notes.push(format!("… and {} more", walk.more_notes));
    }
    let measures = walk.worst.into_iter().map(|(_, measure)| measure).collect();
    Finding { measures, notes: walk.notes }
}

struct Walk<'t> {
    tolerances: &'t Tolerances,
    /// The largest difference per quantity, in order of first appearance.
    worst: Vec<(Quantity, Measure)>,
    notes: Vec<String>,
    more_notes: usize,
}

impl Walk<'_> {
    fn visit(&mut self, a: &Value, b: &Value, path: &mut Vec<String>) {
        match (a, b) {
            (Value::Object(ma), Value::Object(mb)) => {
                for (key, va) in ma {
                    path.push(key.clone());
                    match mb.get(key) {
                        Some(vb) => self.visit(va, vb, path),
                        None => self.note(path, "only in A".into()),
                    }
                    path.pop();
                }
                for key in mb.keys().filter(|k| !ma.contains_key(*k)) {
                    path.push(key.clone());
                    self.note(path, "only in B".into());
                    path.pop();
                }
            }
            (Value::Array(xa), Value::Array(xb)) if xa.len() != xb.len() => {
                self.note(path, format!("{} elements in A, {} in B", xa.len(), xb.len()));
            }
            (Value::Array(xa), Value::Array(xb)) => {
                for (i, (va, vb)) in xa.iter().zip(xb).enumerate() {
                    path.push(format!("[{i}]"));
                    self.visit(va, vb, path);
                    path.pop();
                }
            }
            (Value::Number(na), Value::Number(nb)) if is_integer(na) && is_integer(nb) && !counts_pixels(path) => {
                if na != nb {
                    self.note(path, format!("{na} in A, {nb} in B"));
                }
            }
            (Value::Number(na), Value::Number(nb)) => {
                if let (Some(x), Some(y)) = (na.as_f64(), nb.as_f64()) {
                    self.number(x, y, path);
                }
            }
            _ if a == b => {}
            _ => self.note(path, format!("{} in A, {} in B", brief(a), brief(b))),
        }
    }

    fn number(&mut self, x: f64, y: f64, path: &[String]) {
        let quantity = quantity(path);
        let t = self.tolerances;
        let (name, difference, tolerance, unit) = match quantity {
            Quantity::Length => ("length_abs_m", (x - y).abs(), t.position_m, "m"),
            Quantity::Orientation => ("orientation_abs", (x - y).abs(), t.rotation, "unitless"),
            Quantity::Touch => ("touch_abs", (x - y).abs(), t.touch, "reading"),
            Quantity::Other => ("relative", relative(x, y), t.relative, "relative"),
        };
        match self.worst.iter_mut().find(|(q, _)| *q == quantity) {
            Some((_, worst)) if worst.value >= difference => {}
            Some((_, worst)) => *worst = Measure::new(name, difference, tolerance, unit).at(dotted(path)),
            None => self.worst.push((quantity, Measure::new(name, difference, tolerance, unit).at(dotted(path)))),
        }
    }

    fn note(&mut self, path: &[String], what: String) {
        if self.notes.len() < NOTES {
            self.notes.push(format!("{}: {what}", dotted(path)));
        } else {
            self.more_notes += 1;
        }
    }
}

/// |x − y| relative to the larger magnitude, or to 1 when both are smaller.
fn relative(x: f64, y: f64) -> f64 {
    (x - y).abs() / x.abs().max(y.abs()).max(1.0)
}

fn is_integer(n: &serde_json::Number) -> bool {
    n.is_i64() || n.is_u64()
}

fn counts_pixels(path: &[String]) -> bool {
    path.last().is_some_and(|key| key.ends_with("_px"))
}

fn quantity(path: &[String]) -> Quantity {
    path.iter().rev().filter(|step| !step.starts_with('[')).find_map(|key| named(key)).unwrap_or(Quantity::Other)
}

fn named(key: &str) -> Option<Quantity> {
    match key {
        "p" | "t_w2c" | "t_m2c" | "p_palm" => Some(Quantity::Length),
        "q" | "R_w2c" | "R_m2c" | "n_palm" | "normal" | "joints" | "azimuth" => Some(Quantity::Orientation),
        "reading" | "readings" => Some(Quantity::Touch),
        _ if key.ends_with("_m") => Some(Quantity::Length),
        _ => None,
    }
}

/// `grasp.object_pose.p[0]`.
fn dotted(path: &[String]) -> String {
    let mut out = String::new();
    for step in path {
        if !out.is_empty() && !step.starts_with('[') {
            out.push('.');
        }
        out.push_str(step);
    }
    if out.is_empty() { "(document)".into() } else { out }
}

fn brief(value: &Value) -> String {
    let text = value.to_string();
    if text.chars().count() <= 40 { text } else { format!("{}…", text.chars().take(40).collect::<String>()) }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn meta(x: f64) -> Value {
        json!({
            "sample_id": "can.trx3.g000001.v02",
            "camera": {"K": [[110.8, 0, 63.5], [0, 110.8, 63.5], [0, 0, 1]], "t_w2c": [0.01, 0.02, 0.4],
                       "R_w2c": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "visible_px": 1234},
            "grasp": {"object_pose": {"p": [x, 0.0, 0.05], "q": [1.0, 0.0, 0.0, 0.0]},
                      "joints": {"f0_j0": 0.61},
                      "hold": {"drop_m": 0.003},
                      "touch": {"active": [{"taxel": 12, "reading": 0.61, "p_palm": [0.01, 0.0, 0.02]}],
                                "readings": [0.0, 0.61]}},
        })
    }

    fn worst<'f>(finding: &'f Finding, name: &str) -> &'f Measure {
        finding.measures.iter().find(|m| m.name == name).unwrap_or_else(|| panic!("no {name}: {finding:?}"))
    }

    #[test]
    fn identical_documents_are_within_tolerance_with_zero_differences() {
        let finding = compare(&meta(0.1), &meta(0.1), &Tolerances::default());
        assert!(finding.within() && finding.notes.is_empty(), "{finding:?}");
        assert!(finding.measures.iter().all(|m| m.value == 0.0));
    }

    #[test]
    fn a_pose_a_millimetre_off_is_a_difference_in_metres_at_its_path() {
        let finding = compare(&meta(0.1), &meta(0.101), &Tolerances::default());
        assert!(!finding.within());
        let length = worst(&finding, "length_abs_m");
        assert!((length.value - 0.001).abs() < 1e-12);
        assert_eq!(length.at.as_deref(), Some("grasp.object_pose.p[0]"));
        let close = compare(&meta(0.1), &meta(0.100_000_1), &Tolerances::default());
        assert!(close.within(), "0.1 µm: {close:?}");
    }

    #[test]
    fn numbers_are_judged_by_what_their_key_says_they_measure() {
        let mut b = meta(0.1);
        b["grasp"]["joints"]["f0_j0"] = json!(0.6101);
        b["grasp"]["touch"]["readings"][1] = json!(0.62);
        b["camera"]["visible_px"] = json!(1236);
        b["grasp"]["hold"]["drop_m"] = json!(0.00301);
        let finding = compare(&meta(0.1), &b, &Tolerances::default());
        let (orientation, touch) = (worst(&finding, "orientation_abs"), worst(&finding, "touch_abs"));
        assert!((orientation.value - 1e-4).abs() < 1e-9);
        assert_eq!(orientation.at.as_deref(), Some("grasp.joints.f0_j0"));
        assert!((touch.value - 0.01).abs() < 1e-12);
        assert_eq!(touch.at.as_deref(), Some("grasp.touch.readings[1]"));
        let relative = worst(&finding, "relative");
        assert!((relative.value - 2.0 / 1236.0).abs() < 1e-12);
        assert_eq!(relative.at.as_deref(), Some("camera.visible_px"));
        assert!(!relative.within(), "2 pixels in 1236 are more than 0.1 %");
        assert_eq!(worst(&finding, "length_abs_m").at.as_deref(), Some("grasp.hold.drop_m"));
    }

    #[test]
    fn integers_must_be_equal_and_small_numbers_are_compared_absolutely() {
        let (a, mut b) = (
            json!({"seed": 1234567890123u64, "occlusion": 0.0}),
            json!({"seed": 1234567890124u64, "occlusion": 0.0005}),
        );
        let finding = compare(&a, &b, &Tolerances::default());
        assert_eq!(finding.notes, ["seed: 1234567890123 in A, 1234567890124 in B"]);
        assert!((worst(&finding, "relative").value - 0.0005).abs() < 1e-15, "0.0005 below 1: absolute");
        b["seed"] = json!(1234567890123u64);
        assert!(compare(&a, &b, &Tolerances::default()).within());
    }

    #[test]
    fn keys_array_lengths_types_and_strings_that_differ_are_structural_differences() {
        let mut b = meta(0.1);
        b["grasp"]["touch"]["active"] = json!([]);
        b["grasp"]["extra"] = json!(true);
        b["camera"].as_object_mut().map(|c| c.remove("visible_px"));
        b["sample_id"] = json!("can.trx3.g000001.v03");
        let finding = compare(&meta(0.1), &b, &Tolerances::default());
        assert!(!finding.within());
        assert_eq!(
            finding.notes,
            [
                "camera.visible_px: only in A",
                "grasp.touch.active: 1 elements in A, 0 in B",
                "grasp.extra: only in B",
                "sample_id: \"can.trx3.g000001.v02\" in A, \"can.trx3.g000001.v03\" in B",
            ]
        );
    }
}
