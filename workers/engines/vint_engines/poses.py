"""Rigid poses as they travel in JSON: `{"p": [x, y, z], "q": [w, x, y, z]}` (unit quaternion).

Pure numpy, shared by the grasp writer and the render reader, so both sides agree on the layout.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from vint_engines.protocol import BadInput

Vec = npt.NDArray[np.float64]


def pose_json(p: Sequence[float] | Vec, q: Sequence[float] | Vec) -> dict[str, list[float]]:
    return {"p": [float(v) for v in p], "q": [float(v) for v in q]}


def read_pose(obj: Mapping[str, Any], where: str) -> tuple[Vec, Vec]:
    """Position and unit quaternion (w, x, y, z) from a pose object; BadInput if malformed."""
    try:
        p = np.asarray(obj["p"], dtype=np.float64)
        q = np.asarray(obj["q"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{where}: expected a pose {{p, q}}") from exc
    if p.shape != (3,) or q.shape != (4,) or not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise BadInput(f"{where}: expected p of 3 and q of 4 finite numbers")
    norm = np.linalg.norm(q)
    if norm < 1e-9:
        raise BadInput(f"{where}: zero quaternion")
    return p, q / norm


def quat_to_matrix(q: Sequence[float] | Vec) -> Vec:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(m: Vec) -> Vec:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(m, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    quat = np.asarray(q)
    quat /= np.linalg.norm(quat)
    return -quat if quat[0] < 0 else quat


def pose_matrix(p: Sequence[float] | Vec, q: Sequence[float] | Vec) -> Vec:
    """4×4 homogeneous transform of a pose."""
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(q)
    t[:3, 3] = p
    return t


def quat_multiply(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    """The rotation `b` then `a`, (w, x, y, z) quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )
