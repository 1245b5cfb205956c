//! ARCHITECTURE.md's list of the files a new stage kind touches ("Adding a stage kind"), held to
//! the repository: every file of the code, the migrations, the deployment and the scripts that
//! names the noise stage — the stage the list is counted on — is on the list, and every entry of
//! the list names a file that exists. Tests are not counted (they name stages freely), nor is the
//! code of a Rust file's `#[cfg(test)]` module.

use std::path::{Path, PathBuf};

const STAGE: &str = "noise";

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The entries between the list's markers: each bullet's backticked paths before its " — ".
fn listed() -> Vec<String> {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let (_, rest) = text.split_once("<!-- stage-files:begin -->").expect("the list's begin marker");
    let (list, _) = rest.split_once("<!-- stage-files:end -->").expect("the list's end marker");
    let mut bullets: Vec<String> = Vec::new();
    for line in list.lines() {
        if let Some(item) = line.strip_prefix("- ") {
            bullets.push(item.to_string());
        } else if let (Some(last), true) = (bullets.last_mut(), line.starts_with("  ")) {
            last.push(' ');
            last.push_str(line.trim());
        }
    }
    let mut entries = Vec::new();
    for bullet in bullets {
        let head = bullet.split(" — ").next().unwrap_or_default();
        entries.extend(head.split('`').skip(1).step_by(2).map(|p| p.replace("<stage>", STAGE)));
    }
    entries
}

/// Whether `path` matches `pattern`, segment by segment, where a segment's `*` stands for any
/// run of characters.
fn matches(pattern: &str, path: &str) -> bool {
    let (p, f): (Vec<&str>, Vec<&str>) = (pattern.split('/').collect(), path.split('/').collect());
    p.len() == f.len()
        && p.iter().zip(&f).all(|(p, f)| match p.split_once('*') {
            None => p == f,
            Some((head, tail)) => f.len() >= head.len() + tail.len() && f.starts_with(head) && f.ends_with(tail),
        })
}

/// Whether `text` has `needle` not preceded by an identifier character.
fn names(text: &str, needle: &str) -> bool {
    text.match_indices(needle)
        .any(|(i, _)| !text[..i].chars().next_back().is_some_and(|c| c.is_ascii_alphanumeric() || c == '_'))
}

/// Whether a file names the stage, by its kind.
fn names_the_stage(path: &str, text: &str) -> bool {
    let ext = path.rsplit('.').next().unwrap_or_default();
    match ext {
        "rs" => {
            let code = text.split("#[cfg(test)]").next().unwrap_or_default();
            ["Stage::Noise", "Source::Noise", "noise::", "\"noise\""].iter().any(|n| names(code, n))
        }
        "py" | "sh" => ["vint_engines.noise", "\"noise\"", "'noise'", "--stage noise"].iter().any(|n| text.contains(n)),
        "sql" => text.contains("'noise'"),
        "yaml" | "yml" => names(text, "noise") || text.contains("-noise"),
        _ => false,
    }
}

/// Every file under `dir` (relative to the root), skipping caches and build outputs.
fn files(dir: &str, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(root().join(dir)) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        let rel = format!("{dir}/{name}");
        if ["__pycache__", "target", "node_modules", "tests"].contains(&name.as_str()) || name.starts_with('.') {
            continue;
        }
        // The crates' links to the repository's proto/, migrations/ and catalog/ (there for
        // `cargo package`) show files that are counted where they live.
        if entry.file_type().is_ok_and(|t| t.is_symlink()) {
            continue;
        }
        if entry.path().is_dir() {
            files(&rel, out);
        } else {
            out.push(rel);
        }
    }
}

/// The files that name the stage: the services' and workers' code, the engines, the migrations,
/// the deployment and the scripts.
fn naming_the_stage() -> Vec<String> {
    let mut all = Vec::new();
    for dir in ["services", "workers", "migrations", "deploy", "scripts", "proto"] {
        files(dir, &mut all);
    }
    let mut found: Vec<String> = all
        .into_iter()
        .filter(|f| std::fs::read_to_string(root().join(f)).is_ok_and(|text| names_the_stage(f, &text)))
        .collect();
    found.sort();
    found
}

#[test]
fn every_file_that_names_a_stage_is_on_architectures_list() {
    let listed = listed();
    assert!(listed.len() >= 8, "the list reads as {listed:?}");
    let found = naming_the_stage();
    assert!(
        found.iter().any(|f| f == "services/core/src/stage.rs") && found.iter().any(|f| f.ends_with(".sql")),
        "the scan finds too little: {found:?}"
    );
    let unlisted: Vec<&String> = found.iter().filter(|f| !listed.iter().any(|p| matches(p, f))).collect();
    assert!(
        unlisted.is_empty(),
        "these files name the {STAGE} stage and are not on ARCHITECTURE.md's list of what a new stage kind \
         touches: make them stage-generic (Stage::ALL, the contract's dispatch) or list them: {unlisted:?}"
    );
}

#[test]
fn every_entry_of_architectures_list_is_a_file() {
    let mut all = Vec::new();
    for dir in ["services", "workers", "migrations", "deploy", "scripts", "proto"] {
        files(dir, &mut all);
    }
    for entry in listed() {
        assert!(all.iter().any(|f| matches(&entry, f)), "ARCHITECTURE.md lists {entry}, which names no file");
    }
}

#[test]
fn globs_match_by_segment() {
    assert!(matches("migrations/postgres/*.sql", "migrations/postgres/0004_state_checks.sql"));
    assert!(!matches("migrations/postgres/*.sql", "migrations/postgres/sub/0004.sql"));
    assert!(!matches("a/*.sql", "a/x.py"));
    assert!(names("use contract::noise::X", "noise::") && !names("let denoise::x", "noise::"));
}

/// The code map has a heading for every crate of the workspace.
#[test]
fn every_workspace_crate_has_its_heading_in_the_code_map() {
    let manifest = std::fs::read_to_string(root().join("Cargo.toml")).expect("Cargo.toml");
    let manifest: toml::Table = manifest.parse().expect("Cargo.toml parses");
    let members: Vec<&str> = manifest["workspace"]["members"]
        .as_array()
        .expect("workspace members")
        .iter()
        .filter_map(|m| m.as_str())
        .collect();
    assert!(members.len() >= 10, "{members:?}");
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let (_, map) = text.split_once("## Code map").expect("a code map");
    let map = map.split("\n## ").next().unwrap_or_default();
    let headings: Vec<&str> = map.lines().filter(|l| l.starts_with("### ")).collect();
    for member in members {
        assert!(
            headings.iter().any(|h| h.contains(&format!("`{member}`"))),
            "ARCHITECTURE.md's code map has no heading for the crate {member}: {headings:?}"
        );
    }
}
