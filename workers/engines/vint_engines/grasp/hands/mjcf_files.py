"""What a user's hand MJCF may refer to, judged on its text before MuJoCo parses it.

MuJoCo's parser opens some files as it reads the document — an `<include file=…>`, a
`<model file=…>` to `<attach>`, a `<flexcomp file=…>` — from any path, absolute or relative to the
working directory, so those must be refused before `MjSpec.from_string` sees the text. A hand is
one MJCF file plus the mesh files the submission lists (`mjcf.py` serves each `<mesh file=…>` from
the staged files alone, `mesh_file_path` being the rule). Everything else that names a file is
refused: includes, models and `<attach>`, height fields, skins, flexcomps and any element not
known here; a texture's file (textures are dropped, never read) and the compiler's `meshdir`,
`texturedir` and `assetdir` must stay inside the spec's directory. A document with a DOCTYPE or an
entity declaration is refused before it is parsed at all (no entity can expand, however nested),
and it is parsed by `xml.etree`, which without a DTD expands none. The client checks the same
before it submits (`services/vintctl/src/mjcf.rs`).
"""

from __future__ import annotations

import posixpath
import re
import xml.etree.ElementTree as ET

from vint_engines.errors import BadInput, shown

DECLARATION = re.compile(r"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)
COMPILER_DIRS = ("meshdir", "texturedir", "assetdir")
# Elements whose file MuJoCo reads itself: refused, whatever the path.
OTHER_FILE = {
    "include": "a hand is one MJCF file (paste the included file in)",
    "model": "a hand is one MJCF file (models to <attach> are not supported)",
}
SERVED = "a hand's files are its MJCF and its meshes' files"


def mesh_file_path(mjcf_path: str, meshdir: str, file: str, strippath: bool = False) -> str | None:
    """The spec path of a file an MJCF at spec path `mjcf_path` names (a mesh's, a texture's),
    found as MuJoCo finds it (the file's name alone under `strippath`, joined to `meshdir` or the
    texture's directory, relative to the MJCF's directory), or None when it is absolute or leaves
    the spec's directory."""
    file = file.replace("\\", "/")
    if strippath:
        file = posixpath.basename(file)
    meshdir = meshdir.replace("\\", "/")
    if any(part.startswith("/") or ":" in part for part in (file, meshdir)):
        return None
    path = posixpath.normpath(posixpath.join(posixpath.dirname(mjcf_path), meshdir, file))
    if path == ".." or path.startswith("../"):
        return None
    return path


def check_references(xml: str, where: str, mjcf_path: str) -> None:
    """BadInput, naming the element, attribute and value, for anything in the MJCF document `xml`
    (at spec path `mjcf_path`) that names a file the submission cannot supply (see the module's
    doc), for DOCTYPE and ENTITY declarations, and for text that is not XML."""
    declaration = DECLARATION.search(xml)
    if declaration:
        raise BadInput(
            f"{where}: the document declares <!{declaration[1].upper()}>; a hand's MJCF may declare no "
            "DOCTYPE or entities (they could expand without bound)"
        )
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise BadInput(f"{where}: not a valid MJCF model: not well-formed XML: {exc}") from exc
    compilers = [e for e in root.iter() if e.tag == "compiler"]
    for compiler in compilers:
        for key in COMPILER_DIRS:
            value = compiler.get(key)
            if value is not None and mesh_file_path(mjcf_path, value, "") is None:
                raise BadInput(
                    f"{where}: <compiler {key}={shown(value)}> leaves the spec's directory; {SERVED}, "
                    "beside or below the spec"
                )
    settings = {k: v for c in compilers for k, v in c.attrib.items()}  # a later compiler overrides
    texturedir = settings.get("texturedir", settings.get("assetdir", ""))
    strippath = settings.get("strippath") == "true"
    for element in root.iter():
        if element.tag == "attach":
            raise BadInput(
                f"{where}: <attach model={shown(element.get('model', ''))}>: {OTHER_FILE['model']}"
            )
        for key, value in element.attrib.items():
            if key.startswith("file"):
                _check_file(element.tag, key, value, where, mjcf_path, texturedir, strippath)


def _check_file(
    tag: str, key: str, value: str, where: str, mjcf_path: str, texturedir: str, strippath: bool
) -> None:
    """One `file…` attribute: a mesh's is served from the staged files (`mjcf.py`), a texture's
    must stay inside the spec's directory, any other is refused."""
    if tag == "mesh":
        return
    if tag == "texture":
        if mesh_file_path(mjcf_path, texturedir, value, strippath) is None:
            raise BadInput(
                f"{where}: <texture {key}={shown(value)}> (texturedir {shown(texturedir)}) leaves the "
                "spec's directory"
            )
        return
    rule = OTHER_FILE.get(tag, SERVED)
    raise BadInput(f"{where}: <{tag} {key}={shown(value)}> names a file: {rule}")
