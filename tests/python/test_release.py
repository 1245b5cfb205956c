"""The release files agree with the workspace: `LICENSE` is the licence `Cargo.toml` names,
`CITATION.cff` is valid CFF 1.2 for this version, and `CHANGELOG.md` has this version's section."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]


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


def test_the_changelog_has_a_section_for_this_version() -> None:
    version = workspace_package()["version"]
    changelog = (ROOT / "CHANGELOG.md").read_text()
    headings = re.findall(r"^## \[([^\]]+)\](?::\s*(\S+))?", changelog, re.MULTILINE)
    assert any(version in (name, alias) for name, alias in headings), headings
