"""Checks that object masks can be silhouettes at all, without ground truth.

A silhouette of an object the cameras look at leaves some of the image to the table and
the room around it. A mask that covers (nearly) the whole image says nothing about the
object's shape: a visual hull or a field trained on it fills the whole working volume
(an all-white mask set came out 94 mm off, issue 33). Shared by the mask stage (which
writes or accepts masks) and reconstruction (which reads them).
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from real2sim.formats.errors import UserInputError

#: Share of an image's pixels above which a mask is "full": no silhouette leaves so little background.
FULL_MASK_FRACTION = 0.95


def check_not_full(fractions: Sequence[float], names: Sequence[str], what: str, stacklevel: int = 3) -> None:
    """``fractions``: each mask's share of object pixels (0-1), in the order of ``names`` (the frames).

    UserInputError (one line) when every mask covers more than :data:`FULL_MASK_FRACTION` of its
    image; a RuntimeWarning naming how many and the first when only some do. ``what``: how the
    message names the masks (e.g. "the masks of DATASET")."""
    fractions = np.asarray(fractions, dtype=float)
    full = np.nonzero(fractions > FULL_MASK_FRACTION)[0]
    if len(full) == 0:
        return
    share = f"over {100 * FULL_MASK_FRACTION:.0f} % of the image"
    if len(full) == len(fractions):
        raise UserInputError(f"{what}: every mask covers {share} (least {100 * fractions.min():.1f} %): "
                             "masks must be object silhouettes with background around them")
    first = int(full[0])
    warnings.warn(f"{what}: {len(full)} of {len(fractions)} masks cover {share} (first: {names[first]}, "
                  f"{100 * fractions[first]:.1f} %); no silhouette leaves so little "
                  "background: check these masks", RuntimeWarning, stacklevel=stacklevel)
