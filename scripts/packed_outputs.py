"""Reads a task's packed outputs (`outputs.files`, migration 0013) for scripts and benches that
query the database directly.

The format is written by `services/store/src/outputs.rs` and documented there: a version byte (1),
the media types, then each file in name order as (bytes shared with the previous name, the rest of
the name, media type index, size, 32-byte SHA-256), counts and sizes as unsigned LEB128.

Standard library only.
"""

from typing import NamedTuple


class PackedFile(NamedTuple):
    name: str
    media_type: str
    size: int
    sha256: str

    @property
    def object_key(self) -> str:
        """The object's key in the store: its hash's (vint_artifacts::key_for)."""
        return f"sha256/{self.sha256[:2]}/{self.sha256}"


def unpack(blob: bytes) -> list[PackedFile]:
    """The files of one `outputs.files` value; ValueError when it is not the format."""
    at = 0

    def varint() -> int:
        nonlocal at
        value, shift = 0, 0
        while True:
            if at >= len(blob) or shift > 63:
                raise ValueError("truncated or overlong varint")
            b = blob[at]
            at += 1
            value |= (b & 0x7F) << shift
            if b < 0x80:
                return value
            shift += 7

    def take(n: int) -> bytes:
        nonlocal at
        if at + n > len(blob):
            raise ValueError("truncated")
        chunk = blob[at : at + n]
        at += n
        return chunk

    if take(1) != b"\x01":
        raise ValueError("unknown format version")
    media = [take(varint()).decode() for _ in range(varint())]
    files: list[PackedFile] = []
    previous = b""
    for _ in range(varint()):
        shared = varint()
        name = previous[:shared] + take(varint())
        media_type = media[varint()]
        size = varint()
        files.append(PackedFile(name.decode(), media_type, size, take(32).hex()))
        previous = name
    if at != len(blob):
        raise ValueError("bytes after the last file")
    return files
