"""The Hessian tab's colour key names the colours the images draw."""

from __future__ import annotations

import numpy as np

from backend.optim.hessian_image import GROUP_COLORS, GROUP_ORDER
from viewer.images import GROUP_SWATCHES

HUES = {"green": 1, "blue": 2, "orange": 0}  # the channel that dominates each named colour


def test_the_colour_key_names_the_drawn_colours() -> None:
    assert set(GROUP_SWATCHES) == set(GROUP_ORDER)
    for kind in GROUP_ORDER:
        name = GROUP_SWATCHES[kind].split()[-1]
        rgb = np.array(GROUP_COLORS[kind])
        assert int(np.argmax(rgb)) == HUES[name], (kind, name, rgb)
        if name == "orange":
            assert rgb[1] > rgb[2]
    shared = [k for k in GROUP_ORDER if GROUP_COLORS[k] == GROUP_COLORS["points"]]
    assert shared == ["points", "lines"]  # the key says so
