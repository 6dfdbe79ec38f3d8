# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Text from outside shown on the page as text, never as markup.

The page's panel is markdown, and viser's markdown renders raw HTML (an ``<iframe srcdoc>``
with a script in it runs in the page's origin, with the operator's cookie). Whatever reaches the
panel from outside the station -- the engine's messages and errors (which quote frame ids,
template names, file names), template and waypoint names, labels, frame ids of clouds, service
replies -- goes through :func:`text` where it is put into the markdown; only the station's own
words (the bold field names) are markup.
"""

from __future__ import annotations

import string
import unicodedata

__all__ = ["text"]

#: every ASCII punctuation character: CommonMark lets each be backslash-escaped, which makes it
#: a literal character (no emphasis, link, code span, HTML tag, entity, table or autolink)
_ESCAPED = {ord(c): "\\" + c for c in string.punctuation}


def _shown(c: str) -> str:
    # a line break or other control character would end the line (or start a block)
    return " " if unicodedata.category(c) in ("Cc", "Zl", "Zp") else c


def text(value) -> str:
    """Markdown that renders as exactly ``str(value)``: each ASCII punctuation character
    backslash-escaped, line breaks and control characters shown as spaces."""
    return "".join(_shown(c) for c in str(value)).translate(_ESCAPED)
