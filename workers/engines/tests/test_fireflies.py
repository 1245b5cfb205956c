"""The firefly filter on images whose answer is known: an isolated spike takes its neighbours'
median, a two-pixel highlight and an edge are untouched, and off means the image as it was."""

from __future__ import annotations

import numpy as np

from vint_engines.render.fireflies import despeckle


def test_an_isolated_spike_takes_its_neighbours_median_and_is_counted() -> None:
    image = np.full((9, 9, 3), 40, np.uint8)
    image[4, 4] = (250, 250, 250)
    image[2, 6] = (40, 200, 40)  # a coloured firefly: its brightest channel stands out
    out, count = despeckle(image, 0.3)
    assert count == 2
    assert np.array_equal(out, np.full((9, 9, 3), 40, np.uint8))


def test_a_two_pixel_highlight_an_edge_and_a_small_step_are_kept() -> None:
    image = np.full((9, 9, 3), 40, np.uint8)
    image[4, 4] = image[4, 5] = (250, 250, 250)  # two pixels wide: detail, not a firefly
    image[:, 7:] = 220  # an edge
    image[1, 1] = (100, 100, 100)  # brighter than its neighbours by less than 0.3 of full scale
    out, count = despeckle(image, 0.3)
    assert count == 0 and np.array_equal(out, image)


def test_off_leaves_the_image_as_it_is() -> None:
    image = np.zeros((5, 5, 3), np.uint8)
    image[2, 2] = 255
    out, count = despeckle(image, 0.0)
    assert out is image and count == 0
