"""HDRI files for the tests, written byte by byte (headers that declare what their files do not
hold) or by OpenCV (real, small images), independently of `vint_engines.render.hdri_file`."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

EXR_MAGIC = b"\x76\x2f\x31\x01"


def exr_attribute(name: bytes, kind: bytes, value: bytes) -> bytes:
    return name + b"\0" + kind + b"\0" + struct.pack("<i", len(value)) + value


def box2i(width: int, height: int) -> bytes:
    return struct.pack("<4i", 0, 0, width - 1, height - 1)


def chlist(names: tuple[bytes, ...]) -> bytes:
    """Float channels (pixel type 2), sampled 1 × 1."""
    return b"".join(n + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in names) + b"\0"


def exr_part(width: int, height: int, channels: tuple[bytes, ...] = (b"B", b"G", b"R")) -> bytes:
    """One part's attributes as OpenEXR writes a scan-line image, ended by an empty name."""
    return (
        exr_attribute(b"channels", b"chlist", chlist(channels))
        + exr_attribute(b"compression", b"compression", b"\x00")
        + exr_attribute(b"dataWindow", b"box2i", box2i(width, height))
        + exr_attribute(b"displayWindow", b"box2i", box2i(width, height))
        + exr_attribute(b"lineOrder", b"lineOrder", b"\x00")
        + exr_attribute(b"pixelAspectRatio", b"float", struct.pack("<f", 1.0))
        + exr_attribute(b"screenWindowCenter", b"v2f", struct.pack("<2f", 0.0, 0.0))
        + exr_attribute(b"screenWindowWidth", b"float", struct.pack("<f", 1.0))
        + b"\0"
    )


def exr_header(width: int, height: int, channels: tuple[bytes, ...] = (b"B", b"G", b"R")) -> bytes:
    """A single-part scan-line EXR's magic number, version 2 and header; no pixels follow."""
    return EXR_MAGIC + struct.pack("<i", 2) + exr_part(width, height, channels)


def write_opencv_exr(path: Path, bgr: tuple[float, float, float], width: int = 16, height: int = 8) -> Path:
    """A real OpenEXR image of one colour, written by OpenCV in a child process (its EXR codec is
    off unless OPENCV_IO_ENABLE_OPENEXR is set before its first use)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    image = f"np.full(({height}, {width}, 3), {bgr!r}, np.float32)"
    script = f"import sys, cv2, numpy as np; sys.exit(0 if cv2.imwrite(sys.argv[1], {image}) else 1)"
    env = {**os.environ, "OPENCV_IO_ENABLE_OPENEXR": "1"}
    subprocess.run([sys.executable, "-c", script, str(path)], env=env, check=True, timeout=60)
    return path
