"""One picture per modality, all the same size: the sample's RGB, its clean and noisy depth in one
colour map and range, its segmentation in a fixed colour per label, a grey tile where the dataset
has no such file, and the text drawn on them. Images are BGR uint8, as OpenCV keeps them.

Depth and segmentation are scaled with nearest neighbours (a tile shows the values there are, no
blend of a surface with the background); RGB with area averaging down and bilinear up.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

Image = npt.NDArray[np.uint8]  # (h, w, 3) BGR
Depth = npt.NDArray[np.float32]

TILE_WIDTH = 320  # px; a tile's height keeps the image's aspect ratio
MISSING_GREY = 128
NO_DATA = (0, 0, 0)  # depth without a return, segmentation background
DEPTH_COLOUR_MAP = cv2.COLORMAP_TURBO  # near blue to far red
DEPTH_LEVELS = (26, 230)  # the map's levels for near and far: its dark ends would read as no return
OUT_OF_RANGE_DIM = 2  # depth outside the range: its end's colour at half brightness
FONT = cv2.FONT_HERSHEY_SIMPLEX
FONT_SCALE = 0.4
TEXT_COLOUR = (255, 255, 255)

# Segmentation colours (RGB here, BGR in the images): the object's; each hand link's, in the
# record's id order (tab20 without its oranges and greys, which are the object's and the missing
# tile's, and two saturated colours: enough for the allegro's 17 links); and the other labels' (the
# arm, the table, …), from a palette of their own so a table is the same colour beside any hand
# (today's renderer: the arm's flange and link, then the table, in tan).
# Past a palette's end its colours repeat.
OBJECT_RGB = (255, 127, 14)
HAND_RGB = (
    (31, 119, 180),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (188, 189, 34),
    (23, 190, 207),
    (174, 199, 232),
    (152, 223, 138),
    (255, 152, 150),
    (197, 176, 213),
    (196, 156, 148),
    (247, 182, 210),
    (219, 219, 141),
    (158, 218, 229),
    (255, 255, 0),
    (0, 128, 128),
)
OTHER_RGB = ((72, 61, 139), (95, 158, 160), (205, 170, 125), (128, 0, 0), (85, 107, 47), (0, 0, 128))
HAND_PREFIX = "hand/"


@dataclass(frozen=True)
class TileSize:
    """Tiles of an image of `width` × `height` px: `scale` tile pixels per image pixel."""

    width: int
    height: int
    scale: float

    @staticmethod
    def of(image_width: int, image_height: int) -> TileSize:
        scale = TILE_WIDTH / image_width
        return TileSize(TILE_WIDTH, max(1, round(image_height * scale)), scale)

    def to_tile(self, uv: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Image pixel coordinates (centres on integers) to tile pixel coordinates."""
        return (uv + 0.5) * self.scale - 0.5


def rgb_tile(bgr: Image, size: TileSize) -> Image:
    shrink = size.scale < 1
    return cv2.resize(
        bgr, (size.width, size.height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    )


def valid_depth(depth: Depth) -> npt.NDArray[np.bool_]:
    """Pixels with a return: finite and positive (0 means none; `docs/rendering.md`)."""
    return np.isfinite(depth) & (depth > 0)


def depth_range(depth: Depth) -> tuple[float, float] | None:
    """Nearest and farthest return (m), or None for an image without any."""
    values = depth[valid_depth(depth)]
    return None if values.size == 0 else (float(values.min()), float(values.max()))


def depth_tile(depth: Depth, near: float, far: float, size: TileSize) -> Image:
    """`depth` in the colour map from `near` to `far`, black where there is no return; depth outside
    the range takes its end's colour, dimmed."""
    valid = valid_depth(depth)
    span = far - near
    t = np.where(valid, (np.nan_to_num(depth) - near) / span if span > 0 else 0.5, 0.0)
    low, high = DEPTH_LEVELS
    levels = np.round(low + (high - low) * np.clip(t, 0.0, 1.0)).astype(np.uint8)
    coloured = cv2.applyColorMap(levels, DEPTH_COLOUR_MAP)
    outside = valid & ((depth < near) | (depth > far))
    coloured[outside] //= OUT_OF_RANGE_DIM
    coloured[~valid] = NO_DATA
    return cv2.resize(coloured, (size.width, size.height), interpolation=cv2.INTER_NEAREST)


def segment_colours(names: dict[int, str]) -> dict[int, tuple[int, int, int]]:
    """A BGR colour per segmentation id: black for the background (id 0), the object's colour for
    `object`, the hand palette for `hand/<link>` ids and the other palette for any other label,
    each in id order."""
    colours: dict[int, tuple[int, int, int]] = {}
    hands = others = 0
    for label in sorted(names):
        if label == 0 or names[label] == "background":
            colours[label] = NO_DATA
        elif names[label] == "object":
            colours[label] = bgr(OBJECT_RGB)
        elif names[label].startswith(HAND_PREFIX):
            colours[label] = bgr(HAND_RGB[hands % len(HAND_RGB)])
            hands += 1
        else:
            colours[label] = bgr(OTHER_RGB[others % len(OTHER_RGB)])
            others += 1
    return colours


def segmentation_tile(labels: npt.NDArray[np.integer], names: dict[int, str], size: TileSize) -> Image:
    """Each pixel in its label's colour; an id the record does not name is white."""
    colours = segment_colours(names)
    lut = np.full((int(labels.max(initial=0)) + 1, 3), 255, dtype=np.uint8)
    for label, colour in colours.items():
        if label < len(lut):
            lut[label] = colour
    return cv2.resize(lut[labels], (size.width, size.height), interpolation=cv2.INTER_NEAREST)


def missing_tile(size: TileSize, text: str) -> Image:
    """A grey tile saying why there is no picture."""
    tile = np.full((size.height, size.width, 3), MISSING_GREY, dtype=np.uint8)
    (w, h), _ = cv2.getTextSize(text, FONT, FONT_SCALE, 1)
    put_text(tile, text, ((size.width - w) // 2, (size.height + h) // 2))
    return tile


def put_text(
    image: Image, text: str, origin: tuple[int, int], colour: tuple[int, int, int] = TEXT_COLOUR
) -> None:
    """`text` (ASCII) with its baseline's left end at `origin`."""
    cv2.putText(image, text, origin, FONT, FONT_SCALE, colour, 1, cv2.LINE_AA)


def bgr(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    return (rgb[2], rgb[1], rgb[0])
