"""A user's HDRI judged by its header alone, before Blender or any other decoder opens the file.

A decoder allocates what a header declares before it reads a pixel: a 100-byte `.hdr` that says
`-Y 200000 +X 200000` makes Blender ask for 640 GB. So the render engine reads the header itself
— Radiance's text header and resolution line, OpenEXR's magic number, version and attributes
(`dataWindow`, `displayWindow`, `channels` of every part) — and refuses a file that declares
more than `MAX_HDRI_PIXELS`, or whose header is malformed or cut short. It reads at most
`MAX_HEADER_BYTES` and allocates nothing in proportion to what the file declares. Plain Python:
no Blender, no OpenEXR library.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

from vint_engines.errors import BadInput, shown

# 8192 × 4096 (33.5 Mpx): the largest equirectangular maps HDRI libraries publish ("8K"), far more
# than a render of up to a few megapixels can resolve in its background. Blender holds an HDRI as
# RGBA float32 (16 bytes a pixel: 512 MiB at this size) and the scene keeps turned copies of it,
# so a larger map would cost gigabytes per environment for no visible gain.
MAX_HDRI_PIXELS = 8192 * 4096
MAX_HDRI_SAMPLES = MAX_HDRI_PIXELS * 4  # pixels × channels over all of an EXR's parts: RGBA at the limit
# Real headers are a few lines or a few dozen attributes (well under 64 KiB, a preview image
# included); a header that does not end within this is refused rather than read further.
MAX_HEADER_BYTES = 1 << 20

EXR_MAGIC = b"\x76\x2f\x31\x01"
EXR_TILED, EXR_LONG_NAMES, EXR_DEEP, EXR_MULTIPART = 0x200, 0x400, 0x800, 0x1000
RADIANCE_MAGIC = b"#?"
RESOLUTION = re.compile(rb"([+-])([XY])[ \t]+(\d{1,12})[ \t]+([+-])([XY])[ \t]+(\d{1,12})[ \t]*")


@dataclass(frozen=True)
class HdriSize:
    """What a header declares: width × height of its largest part, and pixel × channel samples
    over all parts (a Radiance file has one part of 3 channels)."""

    width: int
    height: int
    samples: int


def check_hdri(path: Path, where: str) -> HdriSize:
    """The size the HDRI at `path` declares; BadInput naming `where` when it is neither a Radiance
    `.hdr` nor an OpenEXR file, its header is malformed or cut short, or it declares more than
    `MAX_HDRI_PIXELS` (or `MAX_HDRI_SAMPLES`)."""
    with path.open("rb") as file:
        head = file.read(MAX_HEADER_BYTES)
    if head.startswith(EXR_MAGIC):
        size = exr_size(head, where)
    elif head.startswith(RADIANCE_MAGIC):
        size = radiance_size(head, where)
    else:
        raise BadInput(
            f"{where}: not an HDRI Blender may read: a Radiance .hdr starts with '#?', an OpenEXR file "
            f"with the bytes 76 2f 31 01; this one starts with {shown(head[:8])}"
        )
    if size.width * size.height > MAX_HDRI_PIXELS:
        raise BadInput(
            f"{where}: declares {size.width} × {size.height} = {size.width * size.height} pixels, "
            f"more than the limit of {MAX_HDRI_PIXELS} (8192 × 4096)"
        )
    if size.samples > MAX_HDRI_SAMPLES:
        raise BadInput(
            f"{where}: declares {size.samples} samples (pixels × channels over all parts), more than "
            f"the limit of {MAX_HDRI_SAMPLES} (8192 × 4096 × RGBA)"
        )
    return size


def radiance_size(head: bytes, where: str) -> HdriSize:
    """A Radiance file's size: its text header (lines up to an empty one), then the resolution
    line, `-Y height +X width` (or another of the format's orientations)."""
    end = head.find(b"\n\n")
    if end < 0:
        raise BadInput(f"{where}: Radiance header cut short: no empty line ends it within {len(head)} bytes")
    line_end = head.find(b"\n", end + 2)
    if line_end < 0:
        raise BadInput(f"{where}: Radiance header cut short: the resolution line after it does not end")
    line = head[end + 2 : line_end]
    found = RESOLUTION.fullmatch(line)
    if found is None or found[2] == found[5]:
        raise BadInput(
            f"{where}: Radiance resolution line {shown(line[:40])} is not '-Y height +X width' "
            "(signs and order may vary, each axis once)"
        )
    sizes = {found[2]: int(found[3]), found[5]: int(found[6])}
    width, height = sizes[b"X"], sizes[b"Y"]
    if width < 1 or height < 1:
        raise BadInput(f"{where}: Radiance resolution {width} × {height}: both must be at least 1")
    return HdriSize(width, height, width * height * 3)


@dataclass
class _Reader:
    """A cursor over an EXR header's bytes: every read past the end is a header cut short."""

    head: bytes
    where: str
    at: int = 0

    def take(self, count: int) -> bytes:
        if count < 0 or self.at + count > len(self.head):
            raise BadInput(
                f"{self.where}: OpenEXR header cut short (or longer than {MAX_HEADER_BYTES} bytes): "
                f"needs {count} bytes at offset {self.at} of {len(self.head)}"
            )
        self.at += count
        return self.head[self.at - count : self.at]

    def int32(self) -> int:
        value: int = struct.unpack("<i", self.take(4))[0]
        return value

    def name(self, longest: int) -> bytes:
        """A null-terminated name of at most `longest` bytes (empty: the end of a list)."""
        end = self.head.find(b"\0", self.at, self.at + longest + 1)
        if end < 0:
            raise BadInput(
                f"{self.where}: OpenEXR header: no name of at most {longest} bytes at offset {self.at} "
                "(malformed, or cut short)"
            )
        return self.take(end - self.at + 1)[:-1]


def exr_size(head: bytes, where: str) -> HdriSize:
    """An OpenEXR file's size: after the magic number and version, one header (several in a
    multi-part file, an empty one ending the list) of attributes `name type size value`, each
    ended by an empty name. Every part's `dataWindow` and `displayWindow` count."""
    reader = _Reader(head, where)
    reader.take(4)  # the magic number
    version = reader.int32()
    if version & 0xFF != 2:
        raise BadInput(f"{where}: OpenEXR version {version & 0xFF}: only version 2 exists")
    if version & EXR_DEEP:
        raise BadInput(f"{where}: an OpenEXR file of deep data is not an image Blender can light with")
    longest = 255 if version & EXR_LONG_NAMES else 31
    parts: list[tuple[int, int, int]] = []  # (width, height, channels)
    while True:
        if version & EXR_MULTIPART and parts and reader.head[reader.at : reader.at + 1] == b"\0":
            break  # an empty header ends a multi-part file's list
        parts.append(_exr_part(reader, longest, len(parts)))
        if not version & EXR_MULTIPART:
            break
    width, height, _ = max(parts, key=lambda p: p[0] * p[1])
    return HdriSize(width, height, sum(w * h * max(c, 1) for w, h, c in parts))


def _exr_part(reader: _Reader, longest: int, index: int) -> tuple[int, int, int]:
    """One part's header: (width, height) of the larger of its data and display windows, and its
    channel count."""
    where = f"{reader.where}: OpenEXR part {index}"
    windows: dict[bytes, tuple[int, int]] = {}
    channels = 0
    while True:  # every attribute takes bytes: a header without its end runs out of them
        name = reader.name(longest)
        if not name:
            break
        kind = reader.name(longest)
        size = reader.int32()
        if size < 0:
            raise BadInput(f"{where}: attribute {shown(name)} has a negative size {size}")
        value = reader.take(size)
        if name in (b"dataWindow", b"displayWindow"):
            windows[name] = _box2i(value, kind, f"{where}: {name.decode()}")
        elif name == b"channels":
            channels = _channel_count(value)
        elif name == b"type" and value.startswith(b"deep"):
            raise BadInput(f"{where}: part type {shown(value)} is deep data, not an image")
    missing = [n.decode() for n in (b"dataWindow", b"displayWindow") if n not in windows]
    if missing:
        raise BadInput(f"{where}: header lacks the required attribute(s) {missing}")
    width, height = max(windows.values(), key=lambda wh: wh[0] * wh[1])
    return width, height, channels


def _box2i(value: bytes, kind: bytes, where: str) -> tuple[int, int]:
    """(width, height) of a `box2i` (x min, y min, x max, y max; inclusive)."""
    if kind != b"box2i" or len(value) != 16:
        raise BadInput(f"{where}: expected a box2i of 16 bytes, got {shown(kind)} of {len(value)}")
    x_min, y_min, x_max, y_max = struct.unpack("<4i", value)
    width, height = x_max - x_min + 1, y_max - y_min + 1
    if width < 1 or height < 1:
        raise BadInput(f"{where}: ({x_min}, {y_min})–({x_max}, {y_max}) is an empty window")
    return width, height


def _channel_count(value: bytes) -> int:
    """Entries of a `chlist`: a name, then 16 bytes (type, linear, reserved, x and y sampling),
    until an empty name. A malformed list counts what it holds."""
    count, at = 0, 0
    while at < len(value) and value[at] != 0:
        end = value.find(b"\0", at)
        if end < 0:
            break
        at = end + 1 + 16
        count += 1
    return count
