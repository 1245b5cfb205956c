//! Local stand-in for main's harness (main's version wins at merge): the native dataset is
//! `VINT_TEST_NATIVE` (a `vintctl run` output with models/ and dataset.json), converted once with
//! `vintctl convert`.

mod bop;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use vint_tests::{stdout, vintctl};

/// The tiny dataset in the native layout.
pub fn tiny() -> &'static Path {
    static NATIVE: OnceLock<PathBuf> = OnceLock::new();
    NATIVE.get_or_init(|| {
        PathBuf::from(std::env::var("VINT_TEST_NATIVE").expect("VINT_TEST_NATIVE: a native tiny dataset"))
    })
}

/// The tiny dataset in BOP's layout.
pub fn bop() -> &'static Path {
    static BOP: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &BOP.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out-bop");
        let run = vintctl(&["convert", path_str(tiny()), "--out", path_str(&out), "--format", "bop", "--json"]);
        assert!(
            run.status.success(),
            "vintctl convert failed:\n{}\n{}",
            stdout(&run),
            String::from_utf8_lossy(&run.stderr)
        );
        (dir, out)
    })
    .1
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().expect("test paths are UTF-8")
}
