"""A user's hand MJCF reads no file the submission does not supply (`grasp/hands/mjcf_files.py`):
MuJoCo's parser opens `<include>`d and `<model>` files itself, from any path, so each is refused
before it parses the text, as is every other file reference (height fields, skins, flexcomps), a
texture or compiler directory that leaves the spec's directory, and any DOCTYPE or entity
declaration (the billion laughs). Each refusal names the element, the attribute and the value."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from vint_engines.errors import shown
from vint_engines.grasp.hands import load_mjcf_hand
from vint_engines.protocol import BadInput

ASSETS = Path(__file__).resolve().parents[3] / "examples" / "assets"
GRIPPER = (ASSETS / "gripper.xml").read_text(encoding="utf-8")
WHERE = "params.hand.mjcf (hands/grip.xml)"


def load(xml: str) -> object:
    return load_mjcf_hand("grip", xml, WHERE, "hands/grip.xml", {})


def refused(xml: str) -> str:
    with pytest.raises(BadInput) as error:
        load(xml)
    message = str(error.value)
    assert message.startswith(WHERE + ": "), message
    return message


def with_asset(element: str) -> str:
    """The example gripper with `element` in an `<asset>` of its own."""
    assert "<worldbody>" in GRIPPER
    return GRIPPER.replace("<worldbody>", f"<asset>{element}</asset><worldbody>", 1)


@pytest.fixture
def outside(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A complete, valid hand outside the submission (what an include would pull in if read), and
    the working directory set beside it, where MuJoCo resolves a relative include."""
    hand = tmp_path / "outside" / "hand.xml"
    hand.parent.mkdir()
    hand.write_text(GRIPPER)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    return hand


def test_the_example_gripper_loads() -> None:
    assert load(GRIPPER).dof == 4  # type: ignore[attr-defined]


@pytest.mark.parametrize("reference", ["{absolute}", "../outside/hand.xml"])
def test_an_include_is_refused_before_mujoco_reads_it(outside: Path, reference: str) -> None:
    """The included file is a complete hand: had MuJoCo read it, the document would load."""
    file = reference.format(absolute=outside)
    message = refused(f'<mujoco model="grip"><include file="{file}"/></mujoco>')
    assert f"<include file={shown(file)}> names a file: a hand is one MJCF file" in message


def test_a_model_to_attach_and_attach_itself_are_refused(outside: Path) -> None:
    model = f'<model name="arm" file="{outside}"/>'
    assert f"<model file={shown(str(outside))}> names a file" in refused(with_asset(model))
    attach = GRIPPER.replace(
        "</worldbody>", '<body name="x"><attach model="arm" prefix="a_"/></body></worldbody>'
    )
    assert "<attach model='arm'>: a hand is one MJCF file" in refused(attach)


@pytest.mark.parametrize(
    ("element", "written"),
    [
        ('<hfield name="h" file="/etc/passwd" size="1 1 1 1"/>', "<hfield file='/etc/passwd'>"),
        ('<skin file="../../skins/hand.skn"/>', "<skin file='../../skins/hand.skn'>"),
        ('<hfield name="h" file="terrain.png" size="1 1 1 1"/>', "<hfield file='terrain.png'>"),
    ],
)
def test_height_fields_and_skins_from_files_are_refused(element: str, written: str) -> None:
    assert f"{written} names a file: a hand's files are its MJCF and its meshes' files" in refused(
        with_asset(element)
    )


def test_a_flexcomp_from_a_file_is_refused() -> None:
    flex = '<body name="cloth"><flexcomp name="f" type="mesh" file="/etc/passwd" dim="2"/></body>'
    xml = GRIPPER.replace("</worldbody>", flex + "</worldbody>")
    assert "<flexcomp file='/etc/passwd'> names a file" in refused(xml)


@pytest.mark.parametrize(
    ("texture", "written"),
    [
        ('file="/etc/passwd"', "<texture file='/etc/passwd'>"),
        ('file="../../secret.png"', "<texture file='../../secret.png'>"),
        ('builtin="flat" fileright="../../../r.png"', "<texture fileright='../../../r.png'>"),
    ],
)
def test_a_texture_file_outside_the_spec_directory_is_refused(texture: str, written: str) -> None:
    message = refused(with_asset(f'<texture name="t" type="cube" {texture}/>'))
    assert f"{written} (texturedir '') leaves the spec's directory" in message


def test_a_texture_inside_the_spec_directory_is_dropped_and_the_hand_loads() -> None:
    xml = with_asset(
        '<texture name="t" type="2d" file="../textures/grain.png"/><material name="m" texture="t"/>'
    )
    assert load(xml).dof == 4  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("compiler", "written"),
    [
        ('meshdir="/usr/share/meshes"', "<compiler meshdir='/usr/share/meshes'>"),
        ('texturedir="../../textures"', "<compiler texturedir='../../textures'>"),
        ('assetdir="C:/assets"', "<compiler assetdir='C:/assets'>"),
    ],
)
def test_compiler_directories_outside_the_spec_directory_are_refused(compiler: str, written: str) -> None:
    xml = GRIPPER.replace("<worldbody>", f"<compiler {compiler}/><worldbody>", 1)
    assert f"{written} leaves the spec's directory" in refused(xml)


BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE mujoco [
  <!ENTITY lol "lol">
  <!ENTITY lol1 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
  <!ENTITY lol2 "&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;">
  <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
  <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
  <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
  <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
  <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
  <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
  <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
<mujoco model="&lol9;"/>
"""


def test_a_billion_laughs_is_refused_before_any_parse() -> None:
    started = time.perf_counter()
    message = refused(BILLION_LAUGHS)
    assert time.perf_counter() - started < 1.0
    assert "declares <!DOCTYPE>; a hand's MJCF may declare no DOCTYPE or entities" in message
    assert "<!ENTITY>" in refused('<mujoco><!ENTITY x "y"></mujoco>')
    assert "<!DOCTYPE>" in refused("<!doctype mujoco>\n" + GRIPPER)


def test_text_that_is_not_xml_is_refused() -> None:
    assert "not a valid MJCF model: not well-formed XML" in refused("<mujoco><worldbody></mujoco>")
    assert "not a valid MJCF model" in refused("<mujoco>&undefined;</mujoco>")
