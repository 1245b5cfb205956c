"""The touch-vs-vision study's classical pose estimator: weighted point-to-plane ICP of measured
points (camera frame, mm) against samples of the object's model surface (object frame, mm).

Plain numpy. Nearest neighbours are brute force over the model samples in blocks: the clouds are
subsampled to a few hundred points against ~2,000 model samples, where a full distance matrix
costs less than building any index. The solver never raises on bad geometry: an under-constrained
or singular system is damped, flagged `degenerate` and the pose left as it was in the directions
the points cannot see.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

# A direction of the 6-DoF update whose curvature is below this share of the largest is one the
# points do not constrain (a cylinder's spin seen from one side); rotations are scaled by the
# model's radius first, so the ratio compares like with like.
DEGENERATE_RATIO = 1e-6
# Levenberg damping as a share of the mean curvature: keeps unconstrained directions at rest
# without biting into constrained ones.
DAMPING = 1e-4
# Correspondences farther than GATE_FACTOR × the median distance (but never under MIN_GATE_MM)
# are dropped: flying pixels and the depth noise's outliers, once the fit is close.
GATE_FACTOR = 3.0
MIN_GATE_MM = 5.0
NN_BLOCK = 256  # query rows per distance block: 256 × 2,000 floats ≈ 2 MB
# A Gauss–Newton step is trusted up to this far (radians about the model's centre, and mm): from
# a start 20–40 mm and 15–30° off, a linearised step can overshoot into another basin.
MAX_STEP_RAD = math.radians(10.0)
MAX_STEP_MM = 20.0


@dataclass(frozen=True)
class Surface:
    """Area-weighted samples of a model's surface with their outward face normals (object frame)."""

    points: Array  # (m, 3) mm
    normals: Array  # (m, 3) unit
    radius_mm: float  # half the largest bounding-box diagonal: the scale of rotations


def sample_surface(
    vertices: Array, faces: npt.NDArray[np.int64], count: int, rng: np.random.Generator
) -> Surface:
    """`count` points drawn uniformly by area over the triangles, each with its face's normal
    (outward for a consistently wound closed mesh, as the exported models are)."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cross, axis=1)
    keep = area2 > 0
    a, b, c, cross, area2 = a[keep], b[keep], c[keep], cross[keep], area2[keep]
    tri = rng.choice(len(area2), size=count, p=area2 / area2.sum())
    # Uniform barycentric coordinates: fold the unit square's far half back onto the triangle.
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    points = a[tri] + u[:, None] * (b[tri] - a[tri]) + v[:, None] * (c[tri] - a[tri])
    normals = cross[tri] / area2[tri, None]
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    return Surface(points=points, normals=normals, radius_mm=float(np.linalg.norm(extent) / 2.0))


def nearest(queries: Array, surface: Surface) -> tuple[npt.NDArray[np.intp], Array]:
    """Index of each query's nearest surface sample and the distance to it (mm).

    |q - m|² = |m|² - 2 q·m + |q|², accumulated one coordinate at a time in float32 without BLAS:
    a product with an inner dimension of 3 gains nothing from BLAS, whose threads on a shared
    machine only add contention (and whose summation order would depend on the thread count)."""
    index = np.empty(len(queries), dtype=np.intp)
    model = surface.points.T.astype(np.float32)  # (3, m): each coordinate a contiguous row
    model_sq = np.einsum("ij,ij->j", model, model)
    for start in range(0, len(queries), NN_BLOCK):
        block = queries[start : start + NN_BLOCK].astype(np.float32)
        d2 = model_sq[None, :] - 2.0 * block[:, 0:1] * model[0]
        d2 -= 2.0 * block[:, 1:2] * model[1]
        d2 -= 2.0 * block[:, 2:3] * model[2]
        index[start : start + len(block)] = np.argmin(d2, axis=1)
    # The distance itself in float64, from the chosen pairs.
    return index, np.linalg.norm(queries - surface.points[index], axis=1)


@dataclass(frozen=True)
class IcpResult:
    """The model-to-camera pose found (`R`, `t` in mm) and how the fit went."""

    R: Array
    t: Array
    iterations: int
    converged: bool
    degenerate: bool  # some direction was unconstrained (at the last iteration)
    inliers: int  # correspondences used at the last iteration
    rms_mm: float  # weighted RMS point-to-plane residual at the last iteration
    conditioning: float  # smallest over largest curvature of the last iteration's system


def rotation_from_vector(omega: Array) -> Array:
    """Rodrigues: the rotation by |ω| about ω/|ω|."""
    angle = float(np.linalg.norm(omega))
    if angle < 1e-15:
        return np.eye(3)
    k = omega / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


def icp(
    points: Array,
    weights: Array,
    gated: npt.NDArray[np.bool_],
    surface: Surface,
    R0: Array,
    t0: Array,
    max_iterations: int = 40,
    tol_mm: float = 0.01,
) -> IcpResult:
    """Refine the model-to-camera pose (R0, t0) so that `points` (camera frame, mm) lie on the
    model surface, minimising Σ w_i (n_i · (S x_i - y_i))² over the camera-to-model map S, where y_i
    is x_i's nearest surface sample and n_i its normal. Points with `gated` set are dropped when
    farther than the gate (the depth points); the others (taxels: on the surface by construction)
    always count. Fewer than 3 points, or a non-finite system, return the start pose unconverged
    and degenerate."""
    A = np.asarray(R0, dtype=np.float64).T.copy()  # camera → model rotation
    b = -A @ np.asarray(t0, dtype=np.float64)
    scale = max(surface.radius_mm, 1e-9)
    if len(points) < 3:
        return IcpResult(
            R=np.array(R0, dtype=np.float64),
            t=np.array(t0, dtype=np.float64),
            iterations=0,
            converged=False,
            degenerate=True,
            inliers=0,
            rms_mm=math.nan,
            conditioning=0.0,
        )
    degenerate, inliers, rms, iteration, conditioning = True, 0, math.nan, 0, 0.0
    converged = False
    while iteration < max_iterations:
        iteration += 1
        p = points @ A.T + b
        index, dist = nearest(p, surface)
        median = float(np.median(dist[gated])) if gated.any() else 0.0
        use = ~gated | (dist <= max(MIN_GATE_MM, GATE_FACTOR * median))
        inliers = int(use.sum())
        if inliers < 3:
            degenerate = True
            break
        p, n, y, w = p[use], surface.normals[index[use]], surface.points[index[use]], weights[use]
        residual = np.einsum("ij,ij->i", n, p - y)
        # d r / d(ω, δ) for S ← exp(ω) S + δ, with ω scaled by the model radius.
        jac = np.hstack([np.cross(p, n) / scale, n])
        hessian = jac.T @ (w[:, None] * jac)
        gradient = jac.T @ (w * residual)
        rms = float(math.sqrt(np.sum(w * residual**2) / np.sum(w)))
        if not (np.isfinite(hessian).all() and np.isfinite(gradient).all()):
            degenerate = True
            break
        curvature = np.linalg.eigvalsh(hessian)
        conditioning = float(curvature[0] / curvature[-1]) if curvature[-1] > 0 else 0.0
        degenerate = conditioning <= DEGENERATE_RATIO
        damping = DAMPING * max(float(np.trace(hessian)) / 6.0, 1e-300)
        try:
            step = -np.linalg.solve(hessian + damping * np.eye(6), gradient)
        except np.linalg.LinAlgError:
            degenerate = True
            break
        omega, delta = step[:3] / scale, step[3:]
        # Trust region: shrink the whole step (keeping its direction) to the limits.
        shrink = min(
            1.0,
            MAX_STEP_RAD / max(float(np.linalg.norm(omega)), 1e-300),
            MAX_STEP_MM / max(float(np.linalg.norm(delta)), 1e-300),
        )
        omega, delta = omega * shrink, delta * shrink
        turn = rotation_from_vector(omega)
        A, b = turn @ A, turn @ b + delta
        # Converged when the step changes the residuals by less than tol_mm (weighted RMS of J·step):
        # motion along a direction the points do not constrain (a can's spin) changes nothing and
        # must not keep the loop going, nor the correspondences' flicker between neighbours.
        change = jac @ (step * shrink)
        if math.sqrt(float(np.sum(w * change**2) / np.sum(w))) < tol_mm:
            converged = True
            break
    return IcpResult(
        R=A.T,
        t=-A.T @ b,
        iterations=iteration,
        converged=converged,
        degenerate=degenerate,
        inliers=inliers,
        rms_mm=rms,
        conditioning=conditioning,
    )
