"""The object surface a grasp samples: area weighting, outward faces, widths across the closing
direction and the palm frame, each checked against a closed-form answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vint_engines.grasp.surface import ObjectSurface, palm_axes, random_rotation
from vint_engines.objects import build_model, load_catalog

BOX = (0.060, 0.158, 0.210)  # the cracker box's edges


@pytest.fixture(scope="module")
def box() -> ObjectSurface:
    return ObjectSurface.of(build_model(load_catalog()["cracker_box"]).mesh)


def test_points_are_drawn_in_proportion_to_face_area(box: ObjectSurface) -> None:
    x, y, z = BOX
    assert box.area == pytest.approx(2 * (x * y + y * z + x * z))
    rng = np.random.default_rng(5)
    normals = np.array([box.sample(rng)[1] for _ in range(4000)])
    share_x = float(np.mean(np.abs(normals[:, 0]) > 0.99))  # the two 158 x 210 mm faces
    assert share_x == pytest.approx(y * z / (x * y + y * z + x * z), abs=0.03)


def test_sampled_points_lie_on_the_surface_with_outward_normals(box: ObjectSurface) -> None:
    rng = np.random.default_rng(6)
    half = np.array(BOX) / 2
    for _ in range(200):
        point, normal = box.sample(rng)
        axis = int(np.argmax(np.abs(normal)))
        assert point[axis] == pytest.approx(math.copysign(half[axis], normal[axis]), abs=1e-9)
        assert (np.abs(point) <= half + 1e-9).all()


def test_the_width_across_a_face_is_its_edge_and_grows_when_the_palm_turns(box: ObjectSurface) -> None:
    point = np.array([BOX[0] / 2, 0.0, 0.0])
    y, z = np.eye(3)[1], np.eye(3)[2]
    assert box.width_across(point, y, z, 0.035) == pytest.approx(BOX[1])
    assert box.width_across(point, z, y, 0.035) == pytest.approx(BOX[2])
    # Turned by 30°: the strip |q . w| <= h crosses the 158 x 210 face in a polygon whose corners
    # are the face's corners inside the strip and the strip's edges' crossings of the face's
    # edges; the width is that polygon's extent along u (x drops out: u and w have none).
    a, h = math.radians(30.0), 0.035
    u, w = math.cos(a) * y + math.sin(a) * z, -math.sin(a) * y + math.cos(a) * z
    half_y, half_z = BOX[1] / 2, BOX[2] / 2
    corners = [np.array([0.0, sy * half_y, sz * half_z]) for sy in (-1, 1) for sz in (-1, 1)]
    polygon = [c for c in corners if abs(c @ w) <= h]
    for offset in (-h, h):  # points t u + offset w of the strip's edge
        for axis, half in ((1, half_y), (2, half_z)):
            for sign in (-1, 1):
                t = (sign * half - offset * w[axis]) / u[axis]
                q = t * u + offset * w
                if abs(q[1]) <= half_y + 1e-12 and abs(q[2]) <= half_z + 1e-12:
                    polygon.append(q)
    extent = float(np.ptp([q @ u for q in polygon]))
    assert extent > BOX[1]
    assert box.width_across(point, u, w, h) == pytest.approx(extent, rel=1e-6)


def test_a_mug_faces_outwards_outside_and_not_inside() -> None:
    mug = ObjectSurface.of(build_model(load_catalog()["mug"]).mesh)
    rng = np.random.default_rng(7)
    outward = inward = 0
    for _ in range(400):
        point, normal = mug.sample(rng)
        radial = np.array([point[0], point[1], 0.0])
        if abs(normal[2]) > 0.2 or np.linalg.norm(radial) < 0.02 or abs(point[1]) > 0.02 or point[0] > 0:
            continue  # only the walls on the side away from the handle (-x)
        facing_axis = normal @ radial < 0  # the inner wall's normal points at the axis
        assert mug.faces_outward(point, normal) != facing_axis, (point, normal)
        outward, inward = outward + (not facing_axis), inward + facing_axis
    assert outward and inward


@pytest.mark.parametrize("normal", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (1, 1, 1)])
@pytest.mark.parametrize("angle", [0.0, math.pi, 1.0])
def test_the_palm_frame_is_a_rotation_facing_the_surface(normal: tuple[int, int, int], angle: float) -> None:
    n = np.array(normal, dtype=float) / np.linalg.norm(normal)
    axes = palm_axes(n, angle)
    assert np.allclose(axes.T @ axes, np.eye(3)) and np.linalg.det(axes) == pytest.approx(1.0)
    assert np.allclose(axes[:, 2], -n)
    turned = palm_axes(n, angle + math.pi / 2)
    assert turned[:, 0] @ axes[:, 1] == pytest.approx(1.0)  # a quarter turn about the normal


def test_random_rotations_are_unit_and_cover_the_sphere() -> None:
    rng = np.random.default_rng(8)
    quats = np.array([random_rotation(rng) for _ in range(2000)])
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0) and (quats[:, 0] >= 0).all()
    # Uniform rotations turn +z to a uniform direction: its z is uniform on [-1, 1].
    x, y = quats[:, 1], quats[:, 2]
    z_of_axis = 1 - 2 * (x * x + y * y)
    assert np.histogram(z_of_axis, bins=4, range=(-1, 1))[0] == pytest.approx([500] * 4, abs=80)
