# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""How a shown candidate's standing reads to an operator -- the same words in the browser
station, the engine's markers and the demo picture.

A candidate's ``probability`` is shared with "no template fits here" and with every other
template of the library, so a right fit among five templates typically reads 0.3-0.4: an honest
number that reads as doubt. What an operator needs at a glance is the verdict (does it fit?) and
how far it leads: the verdict, and for a fit ranked first its margin over the runner-up -- the
ratio of their probabilities (= of their likelihoods), "3.5x the next". A fit ranked lower says
how it compares with the best instead ("0.30x the best").
"""

from __future__ import annotations

import math

from .registration import NO_MATCH

__all__ = ["standing", "margin_text", "REFUSED_PREFIX"]

#: what a refused best candidate is drawn and labelled as
REFUSED_PREFIX = f"{NO_MATCH} — best guess"


def margin_text(probabilities, shown: int) -> str:
    """'3.5x the next' for the first of ``probabilities`` (best first), '0.30x the best' for a
    later one; '' when there is nothing to compare with."""
    p = [float(v) for v in probabilities]
    if not 0 <= shown < len(p) or len(p) < 2:
        return ""
    if shown == 0:
        if p[1] <= 0 or not math.isfinite(p[0] / p[1]):
            return ""
        ratio = p[0] / p[1]
        return f"{ratio:.1f}x the next" if ratio < 100 else "over 100x the next"
    if p[0] <= 0:
        return ""
    return f"{p[shown] / p[0]:.2f}x the best"


def standing(
    no_match: bool, shown: int, probabilities, fits, primitive: bool = False, said: str = ""
) -> tuple[str, bool]:
    """(text, refused) for the shown candidate of an object: ``no_match`` the object's verdict,
    ``shown`` the index of the shown candidate, ``probabilities`` and ``fits`` (True, False or
    None: not judged) of the candidates best first. ``refused``: the candidate is shown against
    the verdict (no template fits here, or it does not fit) -- drawn as an outline, and
    accepting it is an operator override. A primitive that fits (``primitive``) is the
    verdict's own answer where no template fits: its text is the verdict's (``said``: "no
    template fits here; fitted as a box ..."), not refused."""
    f = list(fits)
    own = f[shown] if 0 <= shown < len(f) else None
    if primitive and own is True:
        return said or f"{NO_MATCH}; fitted as a primitive", False
    refused = bool(no_match) or own is False
    margin = margin_text(probabilities, shown)
    if no_match:
        return (REFUSED_PREFIX if shown == 0 else f"{NO_MATCH} — shown anyway"), True
    if own is False:
        return "does not fit" + (f", {margin}" if margin else ""), refused
    if own is None:
        return "not judged" + (f", {margin}" if margin else ""), refused
    return "fits" + (f", {margin}" if margin else ""), refused
