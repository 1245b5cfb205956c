"""The contact sheet: a header naming the columns, then per sample a caption strip (sample id,
object, hand, occlusion, active taxels, depth range) over one row of tiles — RGB, depth, noisy
depth, segmentation, and the RGB with the grasp's taxels drawn on it.

Every tile has the first sample's tile size (all views of a dataset share one resolution).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vint_engines import depth_file
from vint_engines.preview import tiles
from vint_engines.preview.dataset import (
    DEPTH_FILE,
    NOISY_DEPTH_FILE,
    RGB_FILE,
    SEGMENTATION_FILE,
    PreviewError,
    Sample,
)
from vint_engines.preview.taxels import (
    ProjectedTaxels,
    active_taxels,
    in_view,
    layout_taxels,
    unoccluded,
)
from vint_engines.preview.tiles import Image, TileSize

COLUMNS = ("rgb", "depth", "depth_noisy", "segmentation", "taxels")
TITLES = {  # two lines each
    "rgb": ("RGB", ""),
    "depth": ("depth: near blue to far red (range in", "caption), out of it dim, no return black"),
    "depth_noisy": ("noisy depth: the same colours and", "range, holes black"),
    "segmentation": ("segmentation: object orange, hand", "links, others (arm, table), bg black"),
    "taxels": ("active taxels by reading: cyan low,", "magenta high; a ring is hidden"),
}
HEADER_PX = 36
CAPTION_PX = 20
TEXT_INSET_PX = 6
LINE_PX = 14
STRIP_GREY = 32

READING_COLOUR_MAP = cv2.COLORMAP_COOL  # reading 0 cyan … 1 (saturation, the mean gain) magenta
DOT_RADIUS_PX = 4
OUTLINE = (0, 0, 0)
FAINT_RADIUS_PX = 1
FAINT_ALPHA = 0.45
SUBPIXEL_BITS = 4  # cv2.circle's `shift`: centres to 1/16 px


@dataclass(frozen=True)
class Sheet:
    image: Image
    samples: list[str]
    tile: TileSize


def compose(samples: list[Sample], catalog_dir: Path) -> Sheet:
    """The sheet of `samples`, one row each, in their order."""
    size = TileSize.of(samples[0].camera.width, samples[0].camera.height)
    width = size.width * len(COLUMNS)
    parts = [header(width, size)]
    for sample in samples:
        try:
            row, caption_text = sample_row(sample, size, catalog_dir)
        except (KeyError, TypeError, ValueError, IndexError) as exc:  # a malformed record's field
            raise PreviewError(f"{sample.directory}: malformed sample or grasp record ({exc!r})") from exc
        parts.append(caption(width, caption_text))
        parts.append(np.hstack(row))
    return Sheet(np.vstack(parts), [s.sample_id for s in samples], size)


def sample_row(sample: Sample, size: TileSize, catalog_dir: Path) -> tuple[list[Image], str]:
    """A sample's tiles, in `COLUMNS` order, and its caption."""
    rgb = read_image(sample, RGB_FILE, cv2.IMREAD_COLOR)
    depth = read_depth(sample, DEPTH_FILE)
    noisy = read_depth(sample, NOISY_DEPTH_FILE)
    labels = read_image(sample, SEGMENTATION_FILE, cv2.IMREAD_UNCHANGED)
    if labels is not None and labels.ndim != 2:
        raise PreviewError(f"{sample.directory / SEGMENTATION_FILE}: expected one channel of label ids")
    focus = hand_and_object(labels, sample.segment_names) if labels is not None else None
    span, over = depth_span(depth if depth is not None else noisy, focus)
    near, far = span if span is not None else (0.0, 0.0)

    def depth_column(values: tiles.Depth | None) -> Image:
        if values is None:
            return tiles.missing_tile(size, "not requested")
        return tiles.depth_tile(values, near, far, size)

    row = [
        tiles.rgb_tile(rgb, size) if rgb is not None else tiles.missing_tile(size, "not requested"),
        depth_column(depth),
        depth_column(noisy),
        tiles.segmentation_tile(labels, sample.segment_names, size)
        if labels is not None
        else tiles.missing_tile(size, "not requested"),
        taxel_tile(sample, rgb, depth, size, catalog_dir),
    ]
    depth_text = "no depth" if span is None else f"depth {near:.3f}-{far:.3f} m {over}"
    text = (
        f"{sample.sample_id}   object {sample.object}   hand {sample.hand}   "
        f"occlusion {sample.occlusion:.2f}   active taxels {sample.active_taxels}   {depth_text}"
    )
    return row, text


def hand_and_object(labels: np.ndarray, names: dict[int, str]) -> np.ndarray | None:
    """The pixels of the object and the hand's links, or None when the view shows neither."""
    ids = [k for k, name in names.items() if name == "object" or name.startswith(tiles.HAND_PREFIX)]
    focus = np.isin(labels, ids)
    return focus if focus.any() else None


def depth_span(depth: tiles.Depth | None, focus: np.ndarray | None) -> tuple[tuple[float, float] | None, str]:
    """The colour map's range and what it spans: the depth over the hand and object when the
    segmentation shows them (a table or wall behind would squeeze them into one colour; it is
    drawn dimmed), else over the whole image; None without a return."""
    if depth is None:
        return None, ""
    if focus is not None and focus.shape == depth.shape:
        span = tiles.depth_range(np.where(focus, depth, 0.0))
        if span is not None:
            return span, "on hand and object"
    return tiles.depth_range(depth), "on the whole image"


def taxel_tile(
    sample: Sample,
    rgb: Image | None,
    depth: tiles.Depth | None,
    size: TileSize,
    catalog_dir: Path,
) -> Image:
    """The RGB (dark grey without one) with the layout's seen inactive taxels as faint dots and
    every active taxel in view as a dot coloured by its reading: filled where the depth image
    shows it, a ring where a surface hides it (a contact taxel faces the object, so it is often
    behind its own finger)."""
    tile = (
        tiles.rgb_tile(rgb, size) if rgb is not None else np.full((size.height, size.width, 3), 64, np.uint8)
    )
    camera = sample.camera
    skin = layout_taxels(sample.grasp, camera, catalog_dir)
    if skin is not None:
        seen = in_view(skin, camera) & unoccluded(skin, depth) & (skin.reading <= 0)
        faint = tile.copy()
        for u, v in fixed_point(size.to_tile(skin.uv[seen])):
            cv2.circle(
                faint,
                (u, v),
                FAINT_RADIUS_PX << SUBPIXEL_BITS,
                (255, 255, 255),
                -1,
                cv2.LINE_AA,
                SUBPIXEL_BITS,
            )
        tile = cv2.addWeighted(faint, FAINT_ALPHA, tile, 1 - FAINT_ALPHA, 0)
    active = active_taxels(sample.grasp, camera)
    draw_active(tile, active, in_view(active, camera), unoccluded(active, depth), size)
    return tile


def draw_active(
    tile: Image,
    taxels: ProjectedTaxels,
    shown: np.ndarray,
    seen: np.ndarray,
    size: TileSize,
) -> None:
    """Hidden taxels first, so a seen one is never drawn over."""
    colours = reading_colours(taxels.reading)
    radius = DOT_RADIUS_PX << SUBPIXEL_BITS
    for hidden in (True, False):
        pick = shown & (seen != hidden)
        for (u, v), colour in zip(fixed_point(size.to_tile(taxels.uv[pick])), colours[pick], strict=True):
            bgr = tuple(int(c) for c in colour)
            if hidden:  # a coloured ring inside a black one, to stand out on any background
                cv2.circle(tile, (u, v), radius, OUTLINE, 3, cv2.LINE_AA, SUBPIXEL_BITS)
                cv2.circle(tile, (u, v), radius, bgr, 1, cv2.LINE_AA, SUBPIXEL_BITS)
            else:
                cv2.circle(tile, (u, v), radius, bgr, -1, cv2.LINE_AA, SUBPIXEL_BITS)
                cv2.circle(tile, (u, v), radius, OUTLINE, 1, cv2.LINE_AA, SUBPIXEL_BITS)


def reading_colours(readings: np.ndarray) -> np.ndarray:
    """BGR per reading on a fixed scale from 0 to 1, so that sheets compare."""
    levels = np.round(255 * np.clip(readings, 0.0, 1.0)).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(levels, READING_COLOUR_MAP).reshape(-1, 3)


def fixed_point(uv: np.ndarray) -> list[tuple[int, int]]:
    return [(round(u * (1 << SUBPIXEL_BITS)), round(v * (1 << SUBPIXEL_BITS))) for u, v in uv]


def header(width: int, size: TileSize) -> Image:
    strip = np.full((HEADER_PX, width, 3), STRIP_GREY, dtype=np.uint8)
    for i, column in enumerate(COLUMNS):
        for k, line in enumerate(TITLES[column]):
            tiles.put_text(strip, line, (i * size.width + TEXT_INSET_PX, (k + 1) * LINE_PX))
    return strip


def caption(width: int, text: str) -> Image:
    strip = np.full((CAPTION_PX, width, 3), STRIP_GREY, dtype=np.uint8)
    tiles.put_text(strip, text, (TEXT_INSET_PX, CAPTION_PX - 6))
    return strip


def read_image(sample: Sample, name: str, flags: int) -> np.ndarray | None:
    path = sample.file(name)
    if path is None:
        return None
    image = cv2.imread(str(path), flags)
    if image is None:
        raise PreviewError(f"{path}: not a readable image")
    return image


def read_depth(sample: Sample, stem: str) -> tiles.Depth | None:
    path = sample.depth_file(stem)
    if path is None:
        return None
    try:
        return depth_file.read(path)
    except (OSError, ValueError) as exc:
        raise PreviewError(f"{path}: not a readable depth image ({exc})") from exc


def encode_png(image: Image) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError("OpenCV could not encode the sheet as PNG")
    return data.tobytes()
