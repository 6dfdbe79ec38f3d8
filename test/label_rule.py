# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The verdict held against the label rule the product is scored by (docs/REAL_DATA.md): of the
object's points at least 90% on the fitted surface, and of the scan's points on that surface at
least 90% the object's. A primitive's ``fits`` is the fitter's estimate of that rule from its
own segmentation; where the truth clears or misses the bar by ``MARGIN``, the verdict agrees."""

#: the truth's recall and precision this far from the bar leave the verdict free (the fitter
#: reads the object from its segmentation, not from labels: a few points' difference)
MARGIN = 0.03


def assert_honest(result, score, margin: float = MARGIN) -> None:
    """``result.fits`` agrees with the label ``score`` (realdata.PrimitiveScore) wherever the
    truth clears the bar by ``margin`` on both counts (then it fits) or misses it by ``margin``
    on one (then it is refused)."""
    lowest = min(score.recall, score.precision)
    if lowest >= 0.9 + margin:
        assert result.fits is True, (score.to_dict(), result.reason)
    elif lowest <= 0.9 - margin:
        assert result.fits is False, (score.to_dict(), result.recall, result.precision)
