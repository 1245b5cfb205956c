//! The store's SQL, read from named statements in `sql/postgres/` and `sql/sqlite/`.
//!
//! Every statement the store sends lives in a `.sql` file under `services/store/sql/<dialect>/`,
//! one file per module of this crate, as a block that starts with a line `-- name: <name>`.
//! Comment lines right after it say what the statement does; the rest, up to the next name, is
//! the statement. Both dialects hold the same files with the same names in the same order, so a
//! statement is read side by side in its two spellings, and code asks for one by name:
//! `sql(self.backend, "lease_tasks")?`. Where a dialect needs no statement for a name (Postgres
//! fences completions and records what they made in one statement, SQLite in four), its block is
//! comments only, saying why; asking for it is an error.
//!
//! Values always travel as bind parameters. The text names task, job and attempt states as
//! literals where a partial index serves only a query that names its state (`tasks_ready`,
//! `tasks_leased`); the tests check every such literal against the `vint_core` enums.

use std::collections::HashMap;
use std::sync::OnceLock;

use crate::{Backend, Result, StoreError};

/// The files of each dialect, embedded at compile time; a file missing from either directory
/// fails the build.
macro_rules! statement_files {
    ($($file:literal),* $(,)?) => {
        const POSTGRES_FILES: &[(&str, &str)] = &[$(($file, include_str!(concat!("../sql/postgres/", $file)))),*];
        const SQLITE_FILES: &[(&str, &str)] = &[$(($file, include_str!(concat!("../sql/sqlite/", $file)))),*];
    };
}

statement_files!(
    "connection.sql",
    "jobs.sql",
    "queue.sql",
    "lease.sql",
    "complete.sql",
    "fail.sql",
    "release.sql",
    "reuse.sql",
    "lineage.sql",
    "outputs.sql",
    "depth.sql",
    "failures.sql",
    "footprint.sql",
    "dashboard.sql",
);

/// One named block of a statement file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Statement {
    pub name: &'static str,
    /// What the comment lines after the name say.
    pub doc: String,
    /// The statement; `None` where the dialect needs none under this name.
    pub text: Option<&'static str>,
}

/// The statement `name` of `backend`'s dialect.
pub(crate) fn sql(backend: Backend, name: &'static str) -> Result<&'static str> {
    let statements = dialect(backend)?;
    match statements.get(name) {
        Some(Some(text)) => Ok(text),
        Some(None) => Err(StoreError::Statement(format!("{name:?} has no {} statement", backend_name(backend)))),
        None => Err(StoreError::Statement(format!("no statement is named {name:?} for {}", backend_name(backend)))),
    }
}

type Dialect = HashMap<&'static str, Option<&'static str>>;

/// The statements of `backend`'s dialect by name, parsed once.
fn dialect(backend: Backend) -> Result<&'static Dialect> {
    static POSTGRES: OnceLock<std::result::Result<Dialect, String>> = OnceLock::new();
    static SQLITE: OnceLock<std::result::Result<Dialect, String>> = OnceLock::new();
    let (cell, files) = match backend {
        Backend::Postgres => (&POSTGRES, POSTGRES_FILES),
        Backend::Sqlite => (&SQLITE, SQLITE_FILES),
    };
    cell.get_or_init(|| by_name(files)).as_ref().map_err(|e| StoreError::Statement(e.clone()))
}

fn by_name(files: &[(&'static str, &'static str)]) -> std::result::Result<Dialect, String> {
    let mut out = HashMap::new();
    for (file, text) in files {
        for s in parse(file, text)? {
            if out.insert(s.name, s.text).is_some() {
                return Err(format!("{file}: statement {:?} is named twice", s.name));
            }
        }
    }
    Ok(out)
}

fn backend_name(backend: Backend) -> &'static str {
    match backend {
        Backend::Postgres => "Postgres",
        Backend::Sqlite => "SQLite",
    }
}

/// The named blocks of one file. Before the first name only comments and blank lines may stand
/// (the file's header); a name is lowercase letters, digits and `_`.
pub(crate) fn parse(file: &str, text: &'static str) -> std::result::Result<Vec<Statement>, String> {
    const MARK: &str = "-- name: ";
    let mut out: Vec<Statement> = Vec::new();
    // (name, doc lines, byte offset where the block's text starts, whether the doc has ended)
    let mut current: Option<(&'static str, Vec<&'static str>, usize, bool)> = None;
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let start = offset;
        offset += line.len();
        let trimmed = line.trim();
        if let Some(name) = trimmed.strip_prefix(MARK) {
            if let Some(done) = current.take() {
                out.push(finish(text, done, start));
            }
            let name = name.trim();
            if name.is_empty() || !name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_') {
                return Err(format!("{file}: {name:?} is no statement name (lowercase letters, digits and _)"));
            }
            current = Some((name, Vec::new(), offset, false));
            continue;
        }
        match current.as_mut() {
            None if trimmed.is_empty() || trimmed.starts_with("--") => {}
            None => return Err(format!("{file}: SQL before the first `-- name:` line: {trimmed:?}")),
            Some((_, doc, body_start, doc_ended)) => {
                if !*doc_ended && trimmed.starts_with("--") {
                    doc.push(trimmed.trim_start_matches('-').trim());
                    *body_start = offset;
                } else {
                    *doc_ended = true;
                }
            }
        }
    }
    if let Some(done) = current.take() {
        out.push(finish(text, done, text.len()));
    }
    Ok(out)
}

fn finish(
    text: &'static str,
    (name, doc, start, _): (&'static str, Vec<&'static str>, usize, bool),
    end: usize,
) -> Statement {
    let body = text[start..end].trim().trim_end_matches(';').trim_end();
    let only_comments = body.lines().all(|l| l.trim().is_empty() || l.trim().starts_with("--"));
    Statement { name, doc: doc.join(" "), text: if only_comments { None } else { Some(body) } }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;
    use std::path::{Path, PathBuf};

    use vint_core::{AttemptOutcome, JobState, Stage, TaskState};

    use super::*;

    fn dir(dialect: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("sql").join(dialect)
    }

    fn files_in(dialect: &str) -> BTreeSet<String> {
        std::fs::read_dir(dir(dialect)).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect()
    }

    fn statements(files: &[(&'static str, &'static str)]) -> Vec<(&'static str, Statement)> {
        files.iter().flat_map(|(file, text)| parse(file, text).unwrap().into_iter().map(move |s| (*file, s))).collect()
    }

    #[test]
    fn both_dialects_hold_the_same_files_and_every_file_is_embedded() {
        let embedded: BTreeSet<String> = POSTGRES_FILES.iter().map(|(f, _)| f.to_string()).collect();
        assert_eq!(files_in("postgres"), embedded, "sql/postgres/ against the files sql.rs embeds");
        assert_eq!(files_in("sqlite"), embedded, "sql/sqlite/ against the files sql.rs embeds");
    }

    #[test]
    fn both_dialects_name_the_same_statements_in_the_same_order() {
        let names = |files| statements(files).into_iter().map(|(f, s)| (f, s.name)).collect::<Vec<_>>();
        let (pg, lite) = (names(POSTGRES_FILES), names(SQLITE_FILES));
        assert!(pg.len() > 40, "{} statements", pg.len());
        assert_eq!(pg, lite, "(file, name) of every statement, Postgres against SQLite");
        for backend in [Backend::Postgres, Backend::Sqlite] {
            dialect(backend).unwrap();
        }
    }

    #[test]
    fn a_dialect_without_a_statement_says_why_and_one_dialect_has_it() {
        let pg = statements(POSTGRES_FILES);
        let lite = statements(SQLITE_FILES);
        for ((file, a), (_, b)) in pg.iter().zip(&lite) {
            for s in [a, b] {
                assert!(!s.doc.is_empty(), "{file}: {} says nothing of what it does or why it is absent", s.name);
            }
            assert!(a.text.is_some() || b.text.is_some(), "{file}: {} is a statement in neither dialect", a.name);
        }
    }

    /// Every statement is asked for somewhere in the crate's code, and every name the code asks
    /// for with a literal exists in both dialects.
    #[test]
    fn the_code_asks_for_every_statement_and_only_for_statements_that_exist() {
        let names: BTreeSet<&str> = statements(POSTGRES_FILES).into_iter().map(|(_, s)| s.name).collect();
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut code = String::new();
        for entry in walk(&src) {
            if entry.extension().is_some_and(|e| e == "rs") && !entry.ends_with("sql.rs") {
                code.push_str(&std::fs::read_to_string(&entry).unwrap());
            }
        }
        for name in &names {
            assert!(code.contains(&format!("\"{name}\"")), "statement {name} is never used");
        }
        for asked in asked_names(&code) {
            assert!(names.contains(asked.as_str()), "the code asks for {asked:?}, which no file names");
        }
    }

    fn walk(dir: &Path) -> Vec<PathBuf> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() { out.extend(walk(&p)) } else { out.push(p) }
        }
        out
    }

    /// The literal names in `sql(<backend>, "<name>")` calls.
    fn asked_names(code: &str) -> Vec<String> {
        let mut out = Vec::new();
        for (i, _) in code.match_indices("sql(") {
            let call = &code[i + 4..];
            let Some(close) = call.find(')') else { continue };
            let args = &call[..close];
            if let Some((_, quoted)) = args.split_once('"') {
                out.push(quoted.trim_end_matches('"').to_string());
            }
        }
        assert!(out.len() > 40, "found {} calls", out.len());
        out
    }

    /// A state or stage named in the text is one the enums define: a misspelled literal would
    /// match no row, silently.
    #[test]
    fn every_quoted_name_in_the_statements_is_a_state_stage_or_outcome_or_a_known_constant() {
        let mut known: BTreeSet<String> = BTreeSet::new();
        known.extend(TaskState::ALL.iter().map(|s| s.as_str().to_string()));
        known.extend(JobState::ALL.iter().map(|s| s.as_str().to_string()));
        known.extend(Stage::ALL.iter().map(|s| s.as_str().to_string()));
        known.extend(AttemptOutcome::ALL.iter().map(|s| s.as_str().to_string()));
        // Not states or stages: an encoding, catalog and table names, an empty JSON array, the keys
        // of the lease's inputs, the separator of its list of stages, LIKE's escape.
        let constants = [
            "hex",
            "table",
            "_sqlx_migrations",
            "artifacts",
            "tasks",
            "task_deps",
            "attempts",
            "outputs",
            "[]",
            "task_id",
            "key",
            "files",
            ",",
            "\\",
            "",
        ];
        for (file, s) in statements(POSTGRES_FILES).into_iter().chain(statements(SQLITE_FILES)) {
            let Some(text) = s.text else { continue };
            for literal in quoted(text) {
                let ok = known.contains(&literal) || constants.contains(&literal.as_str()) || literal.starts_with("$.");
                assert!(
                    ok,
                    "{file}: {}: {literal:?} is no task, job or attempt state, stage or known constant",
                    s.name
                );
            }
        }
    }

    /// The single-quoted literals of `text`, comments left out.
    fn quoted(text: &str) -> Vec<String> {
        let code: String = text.lines().map(|l| l.split("--").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
        let mut out = Vec::new();
        let mut rest = code.as_str();
        while let Some(open) = rest.find('\'') {
            let after = &rest[open + 1..];
            let Some(close) = after.find('\'') else { break };
            out.push(after[..close].to_string());
            rest = &after[close + 1..];
        }
        out
    }

    #[test]
    fn the_parser_keeps_docs_bodies_and_absences_apart() {
        let text = "-- header\n\n-- name: one\n-- Does one thing.\nSELECT 1;\n\n-- name: two\n-- Not here: why.\n\n-- name: three\nSELECT\n  3\n";
        let s = parse("t.sql", text).unwrap();
        assert_eq!(s.iter().map(|s| s.name).collect::<Vec<_>>(), ["one", "two", "three"]);
        assert_eq!(s[0].doc, "Does one thing.");
        assert_eq!(s[0].text, Some("SELECT 1"));
        assert_eq!(s[1].text, None);
        assert_eq!(s[2].text, Some("SELECT\n  3"));
        assert!(parse("t.sql", "SELECT 1\n-- name: a\nSELECT 2").unwrap_err().contains("before the first"));
        assert!(parse("t.sql", "-- name: Bad-Name\nSELECT 2").unwrap_err().contains("no statement name"));
        assert!(by_name(&[("a.sql", "-- name: x\nSELECT 1\n-- name: x\nSELECT 2")]).unwrap_err().contains("twice"));
    }
}
