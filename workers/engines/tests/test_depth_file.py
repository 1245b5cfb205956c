"""The one rule for depth files (`vint_engines.depth_file`): a 16-bit PNG of 0.1 mm steps or float32
`.npy` metres, 0 = no reading, read back as float32 metres whichever a directory has."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vint_engines import depth_file
from vint_engines.errors import BadInput

HALF_STEP_M = 0.05e-3


def test_the_png_unit_is_the_contracts_tenth_of_a_millimetre() -> None:
    assert depth_file.unit_m() == pytest.approx(1e-4)


def test_a_png_depth_reads_back_within_half_a_step_of_the_float_depth_on_every_pixel(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.05, 6.55, size=(48, 64)).astype(np.float32)
    depth[0, :8] = 0.0  # no reading stays no reading
    path = depth_file.write(tmp_path / "v00_depth", depth, "png")
    assert path.name == "v00_depth.png"
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == depth.shape
    exact = raw.astype(np.float64) * depth_file.unit_m()
    assert np.abs(exact - depth.astype(np.float64)).max() <= HALF_STEP_M + 1e-12
    back = depth_file.read(path)
    assert back.dtype == np.float32 and np.all(back[0, :8] == 0.0)
    # float32 adds at most half its own step at 6.5 m (2.4e-7 m) to the PNG's half step
    assert np.abs(back.astype(np.float64) - depth.astype(np.float64)).max() <= HALF_STEP_M + 2.4e-7


def test_no_return_and_depths_beyond_uint16_store_as_no_reading() -> None:
    units = depth_file.to_png_units([0.0, -1.0, np.nan, np.inf, 6.5535, 6.55356, 1e10])
    assert units.tolist() == [0, 0, 0, 0, 65535, 0, 0]


def test_an_npy_depth_is_float32_metres_exactly(tmp_path: Path) -> None:
    depth = np.array([[0.0, 0.123456], [1.5, 9.0]], dtype=np.float32)
    path = depth_file.write(tmp_path / "depth_noisy", depth, "npy")
    assert path.name == "depth_noisy.npy"
    assert np.array_equal(depth_file.read(path), depth)


def test_a_directory_is_read_in_whichever_format_it_has(tmp_path: Path) -> None:
    depth_file.write(tmp_path / "depth", np.full((2, 2), 0.5, np.float32), "png")
    depth_file.write(tmp_path / "depth_noisy", np.full((2, 2), 0.7, np.float32), "npy")
    assert depth_file.find(tmp_path, "depth") == tmp_path / "depth.png"
    assert depth_file.find(tmp_path, "depth_noisy") == tmp_path / "depth_noisy.npy"
    assert depth_file.find(tmp_path, "rgb") is None
    assert np.allclose(depth_file.read(tmp_path / "depth.png"), 0.5)


def test_malformed_depth_files_are_bad_input(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "depth.png"), np.zeros((2, 2), np.uint8))
    with pytest.raises(BadInput, match="16-bit"):
        depth_file.read(tmp_path / "depth.png")
    np.save(tmp_path / "depth.npy", np.zeros((2, 2), np.uint16))
    with pytest.raises(BadInput, match="expected a float image"):
        depth_file.read(tmp_path / "depth.npy")
    with pytest.raises(BadInput, match="not one of png, npy"):
        depth_file.write(tmp_path / "depth", np.zeros((2, 2), np.float32), "exr")
