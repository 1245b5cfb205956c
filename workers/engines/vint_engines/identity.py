"""What a stage's engine is, as one hash: the part of a task's reuse key that says which code made
its outputs (`python -m vint_engines identity`, read by the worker at start; PROTOCOL.md).

A stage's identity covers
- its code: every `vint_engines` module the stage's engine can import, found by reading import
  statements (those inside functions too) from `vint_engines.<stage>.engine` and the protocol
  module, with the package `__init__` files on the way and the data files beside them (non-Python
  files in a package's directory and in its plain subdirectories: hand models, the contract
  schema), plus the built-in catalog at the repository root when the stage reads it;
- the libraries it runs on: the installed version of every distribution the runtime lock pins
  (`requirements.lock`), and the Python version.

Nothing is imported to find it, so it costs a fraction of a second and no engine start. A change
to the noise model's code changes the noise stage's identity and leaves the render stage's alone:
its finished tasks stay reusable. The walk is static and errs on the side of including: a module
named by an import anywhere in the closure is in it, whether or not that import runs.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.metadata
import json
import platform
from pathlib import Path

from vint_engines.objects.catalog import CATALOG_DIR
from vint_engines.stages import PACKAGE_DIR, python_stages

PACKAGE = "vint_engines"
LOCK = PACKAGE_DIR.parent / "requirements.lock"

# A new stage's engine has an identity without a list to extend.
STAGES = python_stages()
# Modules whose code reads files outside the package: the directory joins their stage's identity.
DATA_DIRS = {f"{PACKAGE}.objects.catalog": CATALOG_DIR}
# Identity format; bump when what goes into the hash changes.
VERSION = 1


def module_file(name: str) -> Path | None:
    """The source file of a `vint_engines` module, or None when the name is not one (an attribute)."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = PACKAGE_DIR.joinpath(*parts[1:])
    for candidate in (base / "__init__.py", base.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_names(path: Path) -> set[str]:
    """Every module name an import statement in `path` may load, resolved to absolute names."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    own = module_name(path)
    package = own if path.name == "__init__.py" else own.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def closure(roots: list[str]) -> set[Path]:
    """The source files of `roots` and of every `vint_engines` module they import, transitively,
    with the `__init__.py` of every package on the way."""
    seen: set[Path] = set()
    todo = [f for f in (module_file(r) for r in roots) if f is not None]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        parts = module_name(path).split(".")
        for i in range(1, len(parts)):
            init = module_file(".".join(parts[:i]))
            if init is not None:
                todo.append(init)
        for name in imported_names(path):
            found = module_file(name)
            if found is not None:
                todo.append(found)
    return seen


def data_files(package_dir: Path) -> list[Path]:
    """Non-Python files in a package's directory and in its subdirectories that are not packages."""
    found: list[Path] = []
    for entry in sorted(package_dir.iterdir()):
        if entry.name == "__pycache__":
            continue
        if entry.is_file() and entry.suffix not in (".py", ".pyc"):
            found.append(entry)
        elif entry.is_dir() and not (entry / "__init__.py").exists():
            found.extend(p for p in sorted(entry.rglob("*")) if p.is_file() and "__pycache__" not in p.parts)
    return found


def stage_files(stage: str) -> dict[str, Path]:
    """Every file whose bytes make `stage`'s engine what it is, by a stable name."""
    sources = closure([f"{PACKAGE}.{stage}.engine", f"{PACKAGE}.protocol"])
    files = {f"{PACKAGE}/{p.relative_to(PACKAGE_DIR).as_posix()}": p for p in sources}
    for package_dir in {p.parent for p in sources if p.name == "__init__.py"}:
        for p in data_files(package_dir):
            files[f"{PACKAGE}/{p.relative_to(PACKAGE_DIR).as_posix()}"] = p
    for module, directory in DATA_DIRS.items():
        if module_file(module) in sources:
            for p in sorted(directory.rglob("*")):
                if p.is_file():
                    files[f"{directory.name}/{p.relative_to(directory).as_posix()}"] = p
    return files


def pinned_libraries(lock: Path = LOCK) -> dict[str, str]:
    """The installed version of every distribution the runtime lock pins ('absent' if missing)."""
    versions: dict[str, str] = {}
    for line in lock.read_text(encoding="utf-8").splitlines():
        spec = line.split("#", 1)[0].strip()
        if not spec or "==" not in spec:
            continue
        name = spec.split("==", 1)[0].strip()
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "absent"
    return dict(sorted(versions.items()))


def digest_files(files: dict[str, Path]) -> str:
    h = hashlib.sha256()
    for name in sorted(files):
        data = files[name].read_bytes()
        h.update(f"{name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def stage_identity(stage: str, libraries: dict[str, str]) -> dict[str, object]:
    """One stage's identity: the hash, and what went into it (for people reading lineage)."""
    files = stage_files(stage)
    code = digest_files(files)
    python = platform.python_version()
    material = json.dumps(
        {"version": VERSION, "stage": stage, "code": code, "python": python, "libraries": libraries},
        sort_keys=True,
        separators=(",", ":"),
    )
    return {
        "identity": hashlib.sha256(material.encode()).hexdigest(),
        "code": code,
        "files": len(files),
        "python": python,
        "libraries": libraries,
    }


def identities() -> dict[str, dict[str, object]]:
    libraries = pinned_libraries()
    return {stage: stage_identity(stage, libraries) for stage in STAGES}
