"""A user's HDRI is judged by its header before any decoder opens it (`render/hdri_file.py`): a tiny
file that declares gigapixels, or whose header is malformed or cut short, is refused naming the
file, the value and the limit; real files pass with the size they hold."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from hdri_files import EXR_MAGIC, box2i, exr_attribute, exr_header, exr_part, write_opencv_exr

from vint_engines.protocol import BadInput
from vint_engines.render.hdri_file import MAX_HDRI_PIXELS, HdriSize, check_hdri

WHERE = "environment 'lab' (assets/lab.hdr)"
EXAMPLE_HDRI = Path(__file__).resolve().parents[3] / "examples" / "assets" / "lab.hdr"


def written(tmp_path: Path, name: str, content: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(content)
    return path


def refused(path: Path) -> str:
    with pytest.raises(BadInput) as error:
        check_hdri(path, WHERE)
    message = str(error.value)
    assert message.startswith(WHERE + ": "), message
    return message


def test_the_limit_is_an_8k_equirectangular_map() -> None:
    assert MAX_HDRI_PIXELS == 8192 * 4096 == 33_554_432


def test_real_small_files_pass_with_the_size_they_hold(tmp_path: Path) -> None:
    hdr = tmp_path / "lab.hdr"
    assert cv2.imwrite(str(hdr), np.full((8, 16, 3), 0.5, np.float32))
    assert check_hdri(hdr, WHERE) == HdriSize(16, 8, 16 * 8 * 3)
    assert check_hdri(EXAMPLE_HDRI, WHERE) == HdriSize(128, 64, 128 * 64 * 3)
    exr = write_opencv_exr(tmp_path / "lab.exr", (0.5, 0.25, 0.125), width=24, height=12)
    assert check_hdri(exr, WHERE) == HdriSize(24, 12, 24 * 12 * 3)
    by_hand = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y 2 +X 3\n" + bytes(4 * 6)
    assert check_hdri(written(tmp_path, "hand.hdr", by_hand), WHERE) == HdriSize(3, 2, 18)
    at_limit = written(tmp_path, "limit.exr", exr_header(8192, 4096))
    assert check_hdri(at_limit, WHERE) == HdriSize(8192, 4096, MAX_HDRI_PIXELS * 3)


def test_the_bundled_hdris_pass() -> None:
    import bpy  # noqa: F401  (first: Blender's own modules, which the scene imports, come with it)

    from vint_engines.render.scene import environment_dir, environments

    for name in environments():
        size = check_hdri(environment_dir() / f"{name}.exr", name)
        assert 0 < size.width * size.height <= MAX_HDRI_PIXELS


def test_a_radiance_file_declaring_gigapixels_is_refused_without_reading_on(tmp_path: Path) -> None:
    path = written(tmp_path, "huge.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 200000 +X 200000\n")
    message = refused(path)
    assert "200000 × 200000 = 40000000000 pixels" in message
    assert f"limit of {MAX_HDRI_PIXELS} (8192 × 4096)" in message
    other_order = written(tmp_path, "turned.hdr", b"#?RGBE\n\n+X 9000 +Y 5000\n")
    assert "9000 × 5000" in refused(other_order)


def test_an_exr_declaring_gigapixels_is_refused(tmp_path: Path) -> None:
    path = written(tmp_path, "huge.exr", exr_header(100_000, 100_000))
    assert path.stat().st_size < 400
    message = refused(path)
    assert "100000 × 100000 = 10000000000 pixels" in message and str(MAX_HDRI_PIXELS) in message


def test_an_exr_is_judged_by_its_larger_window_its_channels_and_all_its_parts(tmp_path: Path) -> None:
    display = exr_header(16, 8).replace(
        exr_attribute(b"displayWindow", b"box2i", box2i(16, 8)),
        exr_attribute(b"displayWindow", b"box2i", box2i(100_000, 100_000)),
    )
    assert "100000 × 100000" in refused(written(tmp_path, "display.exr", display))

    many_channels = exr_header(8192, 4096, tuple(b"c%d" % i for i in range(8)))
    assert "samples (pixels × channels over all parts)" in refused(
        written(tmp_path, "deep.exr", many_channels)
    )

    multipart = EXR_MAGIC + struct.pack("<i", 2 | 0x1000) + exr_part(8192, 4096) * 3 + b"\0"
    assert "samples" in refused(written(tmp_path, "parts.exr", multipart))
    two_small = EXR_MAGIC + struct.pack("<i", 2 | 0x1000) + exr_part(16, 8) * 2 + b"\0"
    assert check_hdri(written(tmp_path, "two.exr", two_small), WHERE) == HdriSize(16, 8, 2 * 16 * 8 * 3)

    deep = EXR_MAGIC + struct.pack("<i", 2 | 0x800) + exr_part(16, 8)
    assert "deep data" in refused(written(tmp_path, "deep_flag.exr", deep))


def test_every_truncation_of_an_exr_header_is_refused_as_cut_short(tmp_path: Path) -> None:
    header = exr_header(16, 8)
    path = tmp_path / "cut.exr"
    for end in range(4, len(header)):
        path.write_bytes(header[:end])
        message = refused(path)
        assert "cut short" in message, (end, message)


@pytest.mark.parametrize(
    ("content", "rule"),
    [
        (b"#?RADIANCE\nthis is not a picture\n", "no empty line ends it"),
        (b"#?RADIANCE\n\n-Y 8 +X 16", "resolution line after it does not end"),
        (b"#?RADIANCE\n\n-Y eight +X 16\n", "is not '-Y height +X width'"),
        (b"#?RADIANCE\n\n-Y 8 -Y 16\n", "each axis once"),
        (b"#?RADIANCE\n\n-Y 0 +X 16\n", "both must be at least 1"),
        (b"#?RADIANCE\n\n-Y 99999999999999 +X 1\n", "is not '-Y height +X width'"),
        (b"\x89PNG\r\n\x1a\n", "not an HDRI Blender may read"),
        (b"", "not an HDRI Blender may read"),
        (EXR_MAGIC + struct.pack("<i", 1), "OpenEXR version 1"),
        (exr_header(16, 8).replace(b"box2i\0\x10\0\0\0", b"box2i\0\xf0\xff\xff\xff", 1), "negative size"),
        (exr_header(16, 8).replace(b"dataWindow\0box2i", b"dataWindow\0box2f", 1), "expected a box2i"),
        (
            EXR_MAGIC + struct.pack("<i", 2) + exr_attribute(b"dataWindow", b"box2i", bytes(16)) + b"\0",
            "lacks",
        ),
        (
            EXR_MAGIC
            + struct.pack("<i", 2)
            + exr_part(16, 8).replace(box2i(16, 8), struct.pack("<4i", 5, 5, 4, 4)),
            "empty window",
        ),
        (EXR_MAGIC + struct.pack("<i", 2) + b"x" * 40 + b"\0", "no name of at most 31 bytes"),
    ],
)
def test_a_malformed_header_is_refused_naming_the_rule(tmp_path: Path, content: bytes, rule: str) -> None:
    assert rule in refused(written(tmp_path, "bad.hdr", content))
