# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What a shown candidate's standing reads as (core.labels): the verdict first, then the margin
over the runner-up (the ratio of their probabilities) -- never a bare probability."""

import math

from hypothesis import given
from hypothesis import strategies as st

from affordance_registration.core.labels import REFUSED_PREFIX, margin_text, standing

probs = st.lists(st.floats(min_value=1e-6, max_value=1.0), min_size=2, max_size=8).map(
    lambda p: sorted(p, reverse=True)
)


def test_the_words():
    assert standing(False, 0, [0.38, 0.11, 0.1], [True, False, False]) == (
        "fits, 3.5x the next",
        False,
    )
    assert standing(False, 1, [0.38, 0.11, 0.1], [True, False, False]) == (
        "does not fit, 0.29x the best",
        True,
    )
    assert standing(True, 0, [0.2, 0.19], [False, False]) == (REFUSED_PREFIX, True)
    assert standing(True, 1, [0.2, 0.19], [False, None])[1] is True
    assert standing(False, 2, [0.5, 0.2, 0.1], [True, True, None]) == (
        "not judged, 0.20x the best",
        False,
    )
    assert standing(False, 0, [0.9], [True]) == ("fits", False)
    assert margin_text([0.9, 0.001], 0) == "over 100x the next"


@given(probs, st.data())
def test_the_margin_is_the_ratio_and_reads_at_least_one_for_the_leader(p, data):
    shown = data.draw(st.integers(0, len(p) - 1))
    text = margin_text(p, shown)
    value = 100.0 if text.startswith("over") else float(text.split("x")[0])
    ratio = p[0] / p[1] if shown == 0 else p[shown] / p[0]
    assert math.isclose(value, min(ratio, 100.0), rel_tol=0.06, abs_tol=0.006)
    assert (value >= 1.0) if shown == 0 else (value <= 1.0)
    assert text.endswith("the next" if shown == 0 else "the best")


@given(probs, st.data())
def test_refused_exactly_when_the_verdict_or_the_candidate_says_no(p, data):
    fits = data.draw(
        st.lists(st.sampled_from([True, False, None]), min_size=len(p), max_size=len(p))
    )
    no_match = data.draw(st.booleans())
    shown = data.draw(st.integers(0, len(p) - 1))
    text, refused = standing(no_match, shown, p, fits)
    assert refused == (no_match or fits[shown] is False)
    assert ("no template fits here" in text) == no_match
    assert ("p 0." not in text) and text
