"""Lists the members of tar files with Python's own tarfile reader, for the WebDataset tests.

    python tests/python/tar_members.py SHARD.tar...

One JSON line per member: the shard, member name, type, size, mode, uid, gid, mtime, user and
group names, the header's magic and version fields (b"ustar\\0" and b"00" for POSIX ustar), and
the SHA-256 of its data. The Rust test compares them with the native dataset's manifest.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tarfile


def members(path: str) -> list[dict[str, object]]:
    rows: list[dict[str, object]] = []
    with open(path, "rb") as raw, tarfile.open(path, "r:") as tar:
        for member in tar:
            raw.seek(member.offset)
            header = raw.read(512)
            data = tar.extractfile(member)
            digest = hashlib.sha256(data.read() if data else b"").hexdigest()
            rows.append(
                {
                    "shard": path,
                    "name": member.name,
                    "regular": member.isreg(),
                    "size": member.size,
                    "mode": member.mode,
                    "uid": member.uid,
                    "gid": member.gid,
                    "mtime": member.mtime,
                    "uname": member.uname,
                    "gname": member.gname,
                    "magic": header[257:265].decode("latin-1"),
                    "sha256": digest,
                }
            )
    return rows


def main() -> int:
    for path in sys.argv[1:]:
        for row in members(path):
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
