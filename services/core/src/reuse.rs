//! Task reuse by content: a task's key names everything its outputs can depend on, so two tasks
//! with one key make the same files, and a task whose key already has a finished result anywhere
//! in the store need not run.
//!
//! The key is the SHA-256 of
//! - the stage,
//! - the engine's identity: for a Python stage, the hash of the code the stage's engine can import
//!   and of the pinned libraries' installed versions (`vint_engines/identity.py`); for the package
//!   stage, `package::IDENTITY`;
//! - the task's parameters exactly as the planner serialized them (`tasks.params_json`: the
//!   contract types written by serde, the same bytes on every machine for the same plan), and
//! - the content hashes of its inputs (each input: the dependency's task key, the file's name and
//!   its SHA-256), in a fixed order.
//!
//! Inputs enter by content, not by the key of the task that made them: a re-run that makes
//! byte-identical outputs leaves its dependents' keys unchanged (early cutoff). The task's own id
//! and its job are not in the key: a task of another job with the same key is the same work.
//! Bump `KEY_VERSION` when what goes into the key changes.

use sha2::{Digest, Sha256};

use crate::contract;
use crate::stage::Stage;

/// The key format; part of every key.
pub const KEY_VERSION: &str = "vint-task-key/v1";

/// The longest engine identity a worker may declare (a hex digest is 64).
pub const MAX_IDENTITY_LEN: usize = 128;

/// One input of a task: the dependency's task key (e.g. `render/mug/trx3/g000003`), the file's
/// name and its SHA-256 (hex).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Input<'a> {
    pub task_key: &'a str,
    pub name: &'a str,
    pub sha256: &'a str,
}

/// The reuse key of a task (64 hex digits), given all its dependencies' outputs in any order:
/// only those `keyed_input` names enter it.
pub fn task_key(stage: Stage, identity: &str, params_json: &str, inputs: &[Input<'_>]) -> String {
    let mut sorted: Vec<Input<'_>> = inputs.iter().copied().filter(|i| keyed_input(stage, i.name)).collect();
    sorted.sort();
    let mut h = Sha256::new();
    // Every variable-length part is framed by its length, so no two different tuples hash alike.
    let mut part = |bytes: &[u8]| {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    part(KEY_VERSION.as_bytes());
    part(stage.as_str().as_bytes());
    part(identity.as_bytes());
    part(params_json.as_bytes());
    part(&(sorted.len() as u64).to_le_bytes());
    for input in &sorted {
        part(input.task_key.as_bytes());
        part(input.name.as_bytes());
        part(input.sha256.as_bytes());
    }
    hex::encode(h.finalize())
}

/// Whether a dependency's output named `name` enters the key of a `stage` task: the files the
/// stage's engine is given (`contract::reads`; a change to a file it never sees cannot change its
/// outputs), and for the package stage, which reads from the store itself, every one.
pub fn keyed_input(stage: Stage, name: &str) -> bool {
    stage == Stage::Package || contract::reads(stage, name)
}

/// Whether `identity` is one a worker may declare: 1 to `MAX_IDENTITY_LEN` characters from
/// `[A-Za-z0-9._:+-]`.
pub fn valid_identity(identity: &str) -> bool {
    !identity.is_empty()
        && identity.len() <= MAX_IDENTITY_LEN
        && identity.bytes().all(|b| b.is_ascii_alphanumeric() || b"._:+-".contains(&b))
}

/// The identities `python -m vint_engines identity` printed (`{"<stage>": {"identity": "…",
/// …}, …}`), by stage; an error names the first entry that is not a known stage with a valid
/// identity. The worker (which declares them) and `vintctl plan --against` (which keys with them)
/// read them through this one parser.
pub fn parse_identities(stdout: &[u8]) -> Result<std::collections::HashMap<Stage, String>, String> {
    let doc: std::collections::BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(stdout).map_err(|e| format!("not JSON: {e}"))?;
    let mut out = std::collections::HashMap::new();
    for (name, entry) in doc {
        let stage: Stage = name.parse().map_err(|e| format!("{e}"))?;
        let identity = entry
            .get("identity")
            .and_then(serde_json::Value::as_str)
            .filter(|id| valid_identity(id))
            .ok_or_else(|| format!("{name}: no valid \"identity\""))?;
        out.insert(stage, identity.to_string());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identities_parse_by_stage_and_refuse_what_is_not_one() {
        let ok = br#"{"render": {"identity": "py:abc123", "files": 12}, "noise": {"identity": "py:def"}}"#;
        let ids = parse_identities(ok).unwrap();
        assert_eq!((ids[&Stage::Render].as_str(), ids[&Stage::Noise].as_str()), ("py:abc123", "py:def"));
        for (bad, says) in [
            (&br#"{"paint": {"identity": "x"}}"#[..], "paint"),
            (br#"{"render": {"identity": "has space"}}"#, "render: no valid"),
            (br#"{"render": {}}"#, "render: no valid"),
            (b"not json", "not JSON"),
        ] {
            let e = parse_identities(bad).unwrap_err();
            assert!(e.contains(says), "{e}");
        }
    }

    const RENDER: Input<'static> = Input { task_key: "grasp/mug/trx3/c0000", name: "grasps.json", sha256: "aa" };
    const TOUCH: Input<'static> = Input { task_key: "grasp/mug/trx3/c0000", name: "object.ply", sha256: "bb" };

    #[test]
    fn a_key_depends_on_every_part_and_not_on_input_order() {
        let base = task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER, TOUCH]);
        assert_eq!(base.len(), 64);
        assert_eq!(base, task_key(Stage::Render, "id1", r#"{"a":1}"#, &[TOUCH, RENDER]));
        let changed = [
            task_key(Stage::Noise, "id1", r#"{"a":1}"#, &[RENDER, TOUCH]),
            task_key(Stage::Render, "id2", r#"{"a":1}"#, &[RENDER, TOUCH]),
            task_key(Stage::Render, "id1", r#"{"a":2}"#, &[RENDER, TOUCH]),
            task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER]),
            task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER, Input { sha256: "bc", ..TOUCH }]),
            task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER, Input { name: "object2.ply", ..TOUCH }]),
            task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER, Input { task_key: "grasp/x", ..TOUCH }]),
        ];
        // A file the stage's engine is never given (render is not given touch.json) is not in it.
        let unread = Input { task_key: "grasp/mug/trx3/c0000", name: "touch.json", sha256: "cc" };
        assert_eq!(base, task_key(Stage::Render, "id1", r#"{"a":1}"#, &[RENDER, TOUCH, unread]));
        for (i, other) in changed.iter().enumerate() {
            assert_ne!(&base, other, "change {i} left the key unchanged");
        }
    }

    #[test]
    fn parts_are_framed_so_moving_a_boundary_changes_the_key() {
        let a = task_key(Stage::Render, "ab", "c", &[]);
        let b = task_key(Stage::Render, "a", "bc", &[]);
        assert_ne!(a, b);
    }

    #[test]
    fn identities_are_short_plain_tokens() {
        assert!(valid_identity(&"f".repeat(64)));
        assert!(valid_identity("package:1+0.1.0"));
        assert!(!valid_identity(""));
        assert!(!valid_identity(&"f".repeat(MAX_IDENTITY_LEN + 1)));
        assert!(!valid_identity("a b"));
        assert!(!valid_identity("a\nb"));
    }
}
