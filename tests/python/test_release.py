"""The release files agree with the workspace: `LICENSE` is the licence `Cargo.toml` names,
`CITATION.cff` is valid CFF 1.2 for this version, `CHANGELOG.md`'s newest section is this version's,
and every crate takes the one version `Cargo.toml` sets (scripts/release_check.sh runs these
before it packages the crates)."""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import check_packages  # noqa: E402


def workspace_package() -> dict[str, str]:
    return tomllib.loads((ROOT / "Cargo.toml").read_text())["workspace"]["package"]


def test_the_license_file_is_the_licence_cargo_names() -> None:
    assert workspace_package()["license"] == "Apache-2.0"
    text = (ROOT / "LICENSE").read_text()
    assert text.split()[:4] == ["Apache", "License", "Version", "2.0,"], text[:200]
    assert "TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION" in text
    assert text.rstrip().endswith("END OF TERMS AND CONDITIONS")


def test_the_citation_is_cff_for_this_version_and_cites_the_paper() -> None:
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors"):
        assert cff.get(key), f"CITATION.cff lacks {key}"
    assert str(cff["version"]) == workspace_package()["version"]
    assert cff["license"] == workspace_package()["license"]
    for person in [a for r in cff.get("references", []) for a in r["authors"]] + cff["authors"]:
        assert "name" in person or ("family-names" in person and "given-names" in person), person
    (paper,) = [r for r in cff["references"] if "VinT-6D" in r["title"]]
    assert paper["year"] == 2024 and "ICML" in paper["collection-title"]


VERSION = re.compile(r"\d+\.\d+\.\d+(?:-[0-9A-Za-z.-]+)?")


def changelog_versions(text: str) -> list[str]:
    """The versions of the changelog's sections, newest first: `## [0.2.0] - date` names 0.2.0,
    `## [Unreleased]: 0.2.0` the version being prepared, a bare `## [Unreleased]` none."""
    versions = []
    for name, alias in re.findall(r"^## \[([^\]]+)\](?::\s*(\S+))?", text, re.MULTILINE):
        version = next((v for v in (alias, name) if VERSION.fullmatch(v)), None)
        if version:
            versions.append(version)
    return versions


def test_changelog_versions_read_the_headings_newest_first() -> None:
    text = "# Changelog\n\n## [Unreleased]\n\n## [Unreleased]: 0.3.0\n\n## [0.2.0] - 2026-01-02\n## [0.1.0]\n"
    assert changelog_versions(text) == ["0.3.0", "0.2.0", "0.1.0"]


def test_the_changelogs_newest_section_is_this_version() -> None:
    version = workspace_package()["version"]
    versions = changelog_versions((ROOT / "CHANGELOG.md").read_text())
    assert versions, "CHANGELOG.md has no section naming a version (## [X.Y.Z] or ## [Unreleased]: X.Y.Z)"
    assert versions[0] == version, (
        f"CHANGELOG.md's newest section is {versions[0]}, Cargo.toml's [workspace.package] version is "
        f"{version}: a release bumps both"
    )


def test_every_crate_takes_the_workspace_version() -> None:
    """A release bumps `[workspace.package] version`, which every crate inherits, and with it the
    `version` of each member in `[workspace.dependencies]` (what `cargo package` writes in place of
    the path)."""
    workspace = tomllib.loads((ROOT / "Cargo.toml").read_text())["workspace"]
    version = workspace["package"]["version"]
    for member in workspace["members"]:
        version_field = tomllib.loads((ROOT / member / "Cargo.toml").read_text())["package"]["version"]
        assert version_field == {"workspace": True}, f"{member}/Cargo.toml: version = {version_field}"
    paths = {name: dep for name, dep in workspace["dependencies"].items() if "path" in dep}
    assert len(paths) >= 9, sorted(paths)
    for name, dep in paths.items():
        assert dep["path"] in workspace["members"], f"[workspace.dependencies] {name} is no member"
        assert dep.get("version") == version, (
            f"[workspace.dependencies] {name}: version = {dep.get('version')!r}, the workspace's is {version}"
        )


def test_a_package_check_names_what_a_crate_reads_from_outside_it() -> None:
    files = {
        "Cargo.toml": "",
        "catalog/objects.toml": "",
        "src/lib.rs": 'const A: &str = include_str!("../catalog/objects.toml");\n'
        'const B: &str = include_str!("../../../catalog/hands.toml");\n'
        'fn m() { sqlx::migrate!("../../migrations/sqlite"); }\n'
        '#[cfg(test)]\nconst T: &str = include_str!("../../../examples/tiny.toml");\n',
        "src/more.rs": 'const C: &[u8] = include_bytes!("gone.bin");\n',
        "tests/t.rs": 'const D: &str = include_str!("../../../examples/tiny.toml");\n',
        "build.rs": 'fn main() { println!("cargo:rerun-if-changed=../../migrations"); let p = "proto"; }\n',
    }
    found = check_packages.findings(files)
    assert len(found) == 4, found
    assert found[0] == 'build.rs: "cargo:rerun-if-changed=../../migrations" names a path above the package'
    assert "hands.toml" in found[1] and "outside the package" in found[1]
    assert "migrate!" in found[2] and "outside the package" in found[2]
    assert found[3].startswith("src/more.rs") and "names src/gone.bin" in found[3]
    del files["build.rs"]
    files["src/lib.rs"] = 'fn m() { sqlx::migrate!("migrations/sqlite"); }\n'
    del files["src/more.rs"]
    assert check_packages.findings(files) == [
        'src/lib.rs: sqlx::migrate!("migrations/sqlite") names migrations/sqlite'
    ]
    files["migrations/sqlite/0001_core.sql"] = ""
    assert check_packages.findings(files) == []


def test_a_package_check_names_the_linked_files_a_crate_lacks() -> None:
    files = {"proto/vint/v1/jobs.proto": "", "src/lib.rs": ""}
    tracked = ["proto/vint/v1/jobs.proto", "proto/vint/v1/work.proto"]
    (finding,) = check_packages.findings(files, ("proto", tracked))
    assert "1 of the 2 files of proto/" in finding and "work.proto" in finding
    assert check_packages.findings(files | {"proto/vint/v1/work.proto": ""}, ("proto", tracked)) == []
