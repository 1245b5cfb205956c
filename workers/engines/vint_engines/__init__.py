"""vint's Python engines: long-lived processes that a Rust worker drives over a framed protocol.

- `grasp`: MuJoCo grasp trials of a modelled hand on a household object.
- `render`: Blender Cycles renders of the object in hand (RGB, depth, mask, camera).
- `noise`: a Kinect-like depth-noise model (OpenCV + numpy).

`protocol` owns the wire format and the serve loop (see PROTOCOL.md); each stage package owns its
domain code and must not touch stdin/stdout.
"""

from __future__ import annotations

__version__ = "0.1.0"
