"""Reads the `.crate` files `cargo package` wrote and checks that each crate holds what it compiles in.

    check_packages.py PACKAGE_DIR VERSION CRATE...

For each CRATE's `PACKAGE_DIR/CRATE-VERSION.crate` (scripts/release_check.sh runs this):

- every `include_str!`/`include_bytes!` with a literal path, and every `sqlx::migrate!`, in the code
  built into its library and binaries names a file (a directory for `migrate!`) inside the package,
  and its build script names no path starting with `../`.
  That code is each Rust file outside `tests/`, `benches/` and `examples/` up to its first
  `#[cfg(test)]`: a test may read the clone's files, as the workspace runs the tests;
- a crate that links a directory of the repository root in (`services/proto/proto` and the like)
  holds every file git has under it.

This is what building the packages (cargo's verification, `release_check.sh --verify`) would find
missing, read from the tarballs in a second, and it names the file.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tarfile
from pathlib import Path, PurePosixPath

ROOT = Path(__file__).resolve().parents[1]
# The crates that compile in a directory of the repository root, through a link of the same name.
LINKED = {"vint-proto": "proto", "vint-store": "migrations", "vint-core": "catalog"}
INCLUDE = re.compile(r'\binclude_(?:str|bytes)!\(\s*"([^"]+)"\s*\)')
MIGRATE = re.compile(r'\bsqlx::migrate!\(\s*"([^"]+)"\s*\)')
# A string in a build script that names a path above the crate ("../x", "rerun-if-changed=../x").
CLIMB = re.compile(r'"(?:[^"\n]*=)?(\.\./[^"\n]*)"')
NOT_BUILT = ("tests/", "benches/", "examples/")


def resolve(path: PurePosixPath) -> str | None:
    """`path` without `.` and `..`, or None when it climbs above the package's root."""
    parts: list[str] = []
    for part in path.parts:
        if part == "..":
            if not parts:
                return None
            parts.pop()
        elif part != ".":
            parts.append(part)
    return "/".join(parts)


def findings(files: dict[str, str], linked: tuple[str, list[str]] | None = None) -> list[str]:
    """What a package lacks: `files` maps each path in it (relative to the crate's root) to its text
    (empty for non-Rust files); `linked` is a root directory the crate links in and git's files
    under it."""
    dirs = {str(parent) for name in files for parent in PurePosixPath(name).parents}
    found = []
    for name, text in sorted(files.items()):
        if name == "build.rs":
            found += [f"build.rs: {m.group(0)} names a path above the package" for m in CLIMB.finditer(text)]
        if not name.endswith(".rs") or name.startswith(NOT_BUILT):
            continue
        code = text.split("#[cfg(test)]")[0]
        for match in INCLUDE.finditer(code):
            target = resolve(PurePosixPath(name).parent / match.group(1))
            if target not in files:
                found.append(f"{name}: {match.group(0)} names {target or 'a file outside the package'}")
        for match in MIGRATE.finditer(code):
            target = resolve(PurePosixPath(match.group(1)))
            if not target or target not in dirs:
                found.append(f"{name}: {match.group(0)} names {target or 'a directory outside the package'}")
    if linked:
        directory, tracked = linked
        missing = [path for path in tracked if path not in files]
        if not tracked:
            found.append(f"git lists no file under {directory}/")
        elif missing:
            found.append(f"{len(missing)} of the {len(tracked)} files of {directory}/ are missing: {missing}")
    return found


def package_files(crate_file: Path, prefix: str) -> dict[str, str]:
    """The files of a `.crate` (a gzipped tar under `CRATE-VERSION/`): Rust files with their text."""
    files = {}
    with tarfile.open(crate_file, "r:gz") as tar:
        for member in tar.getmembers():
            if not member.isfile() or not member.name.startswith(prefix + "/"):
                continue
            name = member.name[len(prefix) + 1 :]
            data = tar.extractfile(member)
            files[name] = data.read().decode("utf-8") if data and name.endswith(".rs") else ""
    return files


def tracked_files(directory: str) -> list[str]:
    listed = subprocess.run(
        ["git", "ls-files", "--", directory], cwd=ROOT, check=True, capture_output=True, text=True
    )
    return listed.stdout.split()


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    package_dir, version, crates = Path(argv[0]), argv[1], argv[2:]
    failed = False
    for crate in crates:
        crate_file = package_dir / f"{crate}-{version}.crate"
        if not crate_file.is_file():
            print(f"check_packages: {crate_file} does not exist (was {crate} packaged?)", file=sys.stderr)
            failed = True
            continue
        files = package_files(crate_file, f"{crate}-{version}")
        linked = (LINKED[crate], tracked_files(LINKED[crate])) if crate in LINKED else None
        found = findings(files, linked)
        for finding in found:
            print(f"check_packages: {crate}: {finding}", file=sys.stderr)
        failed |= bool(found)
        held = f", all {len(linked[1])} files of {linked[0]}/" if linked else ""
        if not found:
            print(f"check_packages: {crate}-{version}.crate: {len(files)} files{held}; no path leaves it")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
