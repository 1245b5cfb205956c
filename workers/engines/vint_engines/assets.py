"""A task's user files: the files a job's spec brings (a user's hand model and taxel layout, an
object mesh, an HDRI) that the task's parameters name by SHA-256.

The planner lists them in `params.assets` (`{path, sha256, size}`: `path` as the spec names it)
and the worker stages each one as an input named by its SHA-256 (PROTOCOL.md). Engines look
them up here; what a file means is the engine's business.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vint_engines import params as P
from vint_engines.protocol import BadInput, TaskRequest


@dataclass(frozen=True)
class StagedAsset:
    """A user file of the job, staged by the worker: where it is and how the spec names it."""

    path: Path
    spec_path: str


def staged_assets(task: TaskRequest) -> dict[str, StagedAsset]:
    """`params.assets` (the user files the task's parameters name, by SHA-256), each found among
    the task's inputs, which the worker names by the file's SHA-256."""
    out: dict[str, StagedAsset] = {}
    if "assets" not in task.params:
        return out
    for i, item in enumerate(P.items(task.params, "assets", "params")):
        where = f"params.assets[{i}]"
        sha = P.string(item, "sha256", where)
        out[sha] = StagedAsset(task.input_path(sha), P.string(item, "path", where))
    return out


def asset_file(assets: dict[str, StagedAsset], sha: str, where: str) -> StagedAsset:
    """The staged file `sha` names; BadInput naming `where` when the task did not list it."""
    if sha not in assets:
        raise BadInput(f"{where}: {sha!r} is not among params.assets")
    return assets[sha]
