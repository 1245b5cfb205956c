"""The modelled hands (`trx3`, `allegro`) and their taxel layouts: structure, physical plausibility,
the catalog, the layout files and their reader."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from vint_engines.grasp.hands import ALLEGRO, HANDS, TRX3, HandDims, hand_dims
from vint_engines.grasp.hands.catalog import CATALOG_DIR, read_hand_catalog
from vint_engines.grasp.skin import compile_hand, generate_layout
from vint_engines.grasp.taxels import REGIONS, TaxelLayout, layout_differences, parse_layout, read_layout
from vint_engines.protocol import BadInput

TAXELS = {"trx3": 620, "allegro": 679}
ROOT = Path(__file__).resolve().parents[3]


def layout_of(dims: HandDims) -> TaxelLayout:
    return read_layout(read_hand_catalog()[dims.name].taxels_path(), dims.link_names())


def test_the_catalog_lists_every_modelled_hand_with_its_fingers_and_dof() -> None:
    catalog = read_hand_catalog()
    assert set(catalog) == set(HANDS) == {"trx3", "allegro"}
    for name, entry in catalog.items():
        dims = hand_dims(name)
        assert (entry.fingers, entry.dof) == (len(dims.fingers), dims.dof)
        assert entry.taxels_path() == CATALOG_DIR / "hands" / name / "taxels.csv"
    assert (ALLEGRO.dof, len(ALLEGRO.fingers)) == (16, 4)
    assert (TRX3.dof, len(TRX3.fingers)) == (8, 3)


def test_unknown_hands_are_bad_input() -> None:
    with pytest.raises(BadInput, match="unknown hand 'octopus'"):
        hand_dims("octopus")


@pytest.mark.parametrize("dims", HANDS.values(), ids=HANDS)
def test_hands_are_physically_plausible(dims: HandDims) -> None:
    model = compile_hand(dims)
    links = [model.body(name) for name in dims.link_names()]
    total = float(model.body("palm").subtreemass[0])
    assert total == pytest.approx(dims.mass)
    assert 0.4 < total < 1.3
    for body in links[1:]:
        assert 0.005 <= body.mass[0] <= 0.1, body.name  # finger links weigh tens of grams
        inertia = np.sort(body.inertia)
        assert inertia[0] > 0 and inertia[0] + inertia[1] >= inertia[2], body.name
    assert model.njnt == dims.dof + 1  # + the palm's free joint
    for name, joint in dims.joints():
        j, actuator = model.joint(name), model.actuator(name.replace("_j", "_a"))
        assert j.limited[0] and tuple(j.range) == joint.range and joint.range[0] < joint.range[1]
        assert j.armature[0] > 0 and j.damping[0] > 0
        assert actuator.forcelimited[0] and tuple(actuator.forcerange) == (-joint.torque, joint.torque)
        assert 0.1 <= joint.torque <= 2.0  # N·m: small servo motors
        assert actuator.ctrllimited[0] and tuple(actuator.ctrlrange) == joint.range
        assert (
            joint.range[0] <= joint.open <= joint.range[1]
            and joint.range[0] <= joint.closed <= joint.range[1]
        )


def test_allegro_follows_the_published_geometry() -> None:
    assert ALLEGRO.palm_half == pytest.approx((0.0475, 0.0565, 0.0204))
    assert ALLEGRO.mass == pytest.approx(1.08, abs=0.02)
    index, middle, ring, thumb = ALLEGRO.fingers
    assert [f.base[1] for f in (index, middle, ring)] == pytest.approx([0.0435, 0.0, -0.0435])
    for finger in (index, middle, ring):
        assert [link.length for link in finger.links] == pytest.approx([0.0164, 0.054, 0.0384, 0.0267])
        assert finger.links[0].joint.kind == "abduct" and finger.links[0].joint.range == (-0.47, 0.47)
        assert [link.joint.range for link in finger.links[1:]] == [
            (-0.196, 1.61),
            (-0.174, 1.709),
            (-0.227, 1.618),
        ]
        assert finger.tip_radius == 0.012
        assert finger.links[-1].length + finger.tip_radius == pytest.approx(0.0387, abs=0.006)
    assert [link.joint.range for link in thumb.links] == [
        (0.263, 1.396),
        (-0.105, 1.163),
        (-0.189, 1.644),
        (-0.162, 1.719),
    ]


def test_trx3_has_two_three_joint_fingers_and_a_two_joint_thumb() -> None:
    assert [len(finger.links) for finger in TRX3.fingers] == [3, 3, 2]
    assert TRX3.joint_names() == ["f0_j0", "f0_j1", "f0_j2", "f1_j0", "f1_j1", "f1_j2", "f2_j0", "f2_j1"]
    assert TRX3.link_names()[0] == "palm" and all(link.startswith("f") for link in TRX3.link_names()[1:])


@pytest.mark.parametrize("dims", HANDS.values(), ids=HANDS)
def test_taxel_layouts_cover_tips_pulps_and_palm_of_the_hand(dims: HandDims) -> None:
    layout = layout_of(dims)
    assert len(layout) == TAXELS[dims.name]
    assert set(layout.links) <= set(dims.link_names())
    assert set(layout.regions) == set(REGIONS)
    for i in range(len(dims.fingers)):
        assert f"f{i}_tip" in layout.links  # every fingertip feels
    assert {link for link, region in zip(layout.links, layout.regions, strict=True) if region == "palm"} == {
        "palm"
    }
    assert np.allclose(np.linalg.norm(layout.normals, axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("dims", HANDS.values(), ids=HANDS)
def test_taxels_lie_on_their_link_surface_with_outward_normals(dims: HandDims) -> None:
    model, layout = compile_hand(dims), layout_of(dims)
    for link, indices in layout.indices_by_link().items():
        body = model.body(link).id
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body and model.geom_contype[g]]
        p, n = layout.positions[indices], layout.normals[indices]

        def surface_distance(points: np.ndarray, geoms: list[int] = geoms) -> np.ndarray:
            return np.min([link_geom_distance(model, g, points) for g in geoms], axis=0)

        assert np.abs(surface_distance(p)).max() < 2e-6, link  # on the surface (CSV keeps µm)
        assert (surface_distance(p + 1e-4 * n) > 5e-5).all(), link  # the normal points out
        assert (surface_distance(p - 1e-4 * n) < -5e-5).all(), link


def link_geom_distance(model: mujoco.MjModel, geom: int, points: np.ndarray) -> np.ndarray:
    """Signed distance of link-frame points to one geom (box, sphere or capsule), written here
    independently of `vint_engines.grasp.skin`."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
    local = (points - model.geom_pos[geom]) @ rotation.reshape(3, 3)
    size, kind = model.geom_size[geom], model.geom_type[geom]
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.linalg.norm(local, axis=1) - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        nearest = np.stack(
            [np.zeros(len(local)), np.zeros(len(local)), np.clip(local[:, 2], -size[1], size[1])], 1
        )
        return np.linalg.norm(local - nearest, axis=1) - size[0]
    assert kind == mujoco.mjtGeom.mjGEOM_BOX
    excess = np.abs(local) - size
    return np.linalg.norm(np.maximum(excess, 0.0), axis=1) + np.minimum(excess.max(axis=1), 0.0)


@pytest.mark.parametrize("dims", HANDS.values(), ids=HANDS)
def test_committed_layouts_are_what_the_generator_makes_on_this_cpu(dims: HandDims) -> None:
    """The committed layouts are up to date: the same taxels, links and regions in the same order,
    positions and normals within one unit of the last written digit (a value on a half-micrometre
    may round the other way on another CPU); `scripts/gen_taxels.py --check` asks the same."""
    committed = layout_of(dims)
    assert layout_differences(committed, generate_layout(dims)) == []


def test_the_generator_writes_identical_files_twice_on_one_machine() -> None:
    first, second = generate_layout(TRX3).to_csv(), generate_layout(TRX3).to_csv()
    assert first == second


def test_the_layout_comparison_allows_a_last_digit_and_nothing_more() -> None:
    committed = layout_of(TRX3)

    def moved(index: int, by: float, normal: bool = False) -> TaxelLayout:
        positions, normals = committed.positions.copy(), committed.normals.copy()
        (normals if normal else positions)[index, 1] += by
        return TaxelLayout(committed.links, positions, normals, committed.regions)

    assert layout_differences(committed, moved(7, 1e-6)) == []
    assert layout_differences(committed, moved(7, 1e-6, normal=True)) == []
    assert layout_differences(committed, moved(7, 3e-6))[0].startswith("taxel 7 on palm: position")
    assert layout_differences(committed, moved(7, 3e-6, normal=True))[0].startswith("taxel 7 on palm")
    swapped = TaxelLayout(
        committed.links, committed.positions, committed.normals, ("tip", *committed.regions[1:])
    )
    assert layout_differences(committed, swapped) == ["taxel 0: palm/palm committed, palm/tip generated"]
    shorter = TaxelLayout(
        committed.links[:-1], committed.positions[:-1], committed.normals[:-1], committed.regions[:-1]
    )
    assert layout_differences(committed, shorter) == [
        f"{len(committed)} taxels committed, {len(committed) - 1} generated"
    ]


AVX512 = ("AVX512F", "AVX512CD", "AVX512_SKX", "AVX512_CLX", "AVX512_CNL", "AVX512_ICL", "AVX512_SPR")


def test_layouts_generated_without_avx512_match_the_committed_files() -> None:
    """Another CPU, emulated: numpy's AVX-512 code paths switched off (NPY_DISABLE_CPU_FEATURES)
    and OpenBLAS on its AVX2 kernels, as on a machine without AVX-512. The generator there must
    agree with the committed layouts, built-in and example, by the `--check` rule."""
    features = numpy_cpu_features()
    present = [name for name in AVX512 if features.get(name)]
    if not present:
        pytest.skip("this CPU has no AVX-512: the other tests already run the AVX2 paths")
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(present), "OPENBLAS_CORETYPE": "Haswell"}
    assert not numpy_cpu_features(env)["AVX512F"]  # the switch took
    script = [sys.executable, str(ROOT / "scripts" / "gen_taxels.py"), "--check"]
    gripper = [
        "--mjcf",
        "examples/assets/gripper.xml",
        "--count",
        "240",
        "--out",
        "examples/assets/gripper_taxels.csv",
    ]
    for command in (script, [*script, *gripper]):
        run = subprocess.run(
            command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=False
        )
        assert run.returncode == 0, run.stderr


def numpy_cpu_features(env: dict[str, str] | None = None) -> dict[str, bool]:
    """numpy's view of the CPU's SIMD features, in a fresh interpreter under `env`."""
    probe = "import json, numpy._core._multiarray_umath as m; print(json.dumps(m.__cpu_features__))"
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


GOOD_ROWS = [
    "taxel,link,x,y,z,nx,ny,nz,region",
    "0,palm,0.01,0.0,0.012,0,0,1,palm",
    "1,f0_tip,0.0,0.0,0.03,0.6,0,0.8,tip",
]


@pytest.mark.parametrize(
    ("line", "bad_row", "message"),
    [
        (3, "1,f9_tip,0.0,0.0,0.03,0.6,0,0.8,tip", "unknown link 'f9_tip'"),
        (3, "1,f0_tip,0.0,0.0,0.03,0.6,0,0.9,tip", "not a unit vector"),
        (3, "1,f0_tip,0.0,0.0,0.03,0.6,0,0.8,knuckle", "region 'knuckle'"),
        (3, "7,f0_tip,0.0,0.0,0.03,0.6,0,0.8,tip", "out of sequence"),
        (3, "1,f0_tip,0.0,nan,0.03,0.6,0,0.8,tip", "not finite"),
        (3, "1,f0_tip,0.0,0.0,0.03,0.6,0,tip", "expected 9 fields"),
        (1, "", "expected the header"),
    ],
)
def test_the_layout_reader_names_the_offending_line(line: int, bad_row: str, message: str) -> None:
    rows = [*GOOD_ROWS[:-1], bad_row] if line > 1 else ["taxel,link,x,y,z", *GOOD_ROWS[1:]]
    with pytest.raises(BadInput, match=rf"user.csv: line {line}: .*{message}"):
        parse_layout("\n".join(rows), TRX3.link_names(), "user.csv")


def test_a_user_layout_loads_the_same_way(tmp_path: Path) -> None:
    path = tmp_path / "scanned.csv"
    path.write_text("\n".join(GOOD_ROWS) + "\n")
    layout = read_layout(path, TRX3.link_names())
    assert layout.links == ("palm", "f0_tip") and layout.regions == ("palm", "tip")
    assert np.allclose(layout.positions[1], [0.0, 0.0, 0.03]) and math.isclose(layout.normals[1][2], 0.8)
    (tmp_path / "again.csv").write_text(layout.to_csv())
    again = read_layout(tmp_path / "again.csv", TRX3.link_names())
    assert again.links == layout.links and np.array_equal(again.positions, layout.positions)
