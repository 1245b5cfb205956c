"""scripts/packed_outputs.py reads what the store packs: the golden bytes that
services/store/src/outputs.rs pins its writer to, read from that file."""

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
from packed_outputs import unpack  # noqa: E402


def golden() -> bytes:
    source = (ROOT / "services" / "store" / "src" / "outputs.rs").read_text()
    found = re.search(r'const GOLDEN: &str = "([0-9a-f]+)";', source)
    assert found, "outputs.rs pins its format in a GOLDEN constant"
    return bytes.fromhex(found.group(1))


def test_the_golden_bytes_read_as_the_files_the_writer_packed() -> None:
    files = unpack(golden())
    assert [(f.name, f.media_type, f.size) for f in files] == [
        ("mug.trx3.g000012.v05/depth.npy", "application/x-npy", 1),
        ("mug.trx3.g000012.v05/rgb.png", "image/png", 300),
    ]
    assert [f.sha256 for f in files] == ["b" * 64, "a" * 64]
    assert files[1].object_key == "sha256/aa/" + "a" * 64


@pytest.mark.parametrize("cut", [1, 5, 40, -1])
def test_truncated_or_padded_bytes_are_refused(cut: int) -> None:
    with pytest.raises(ValueError):
        unpack(golden()[:cut])
    with pytest.raises(ValueError):
        unpack(golden() + b"\x00")
