# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Package exceptions. Core code raises these with a message a person can act on."""


class AffordanceError(Exception):
    """Base class of every error the package raises on purpose."""


class TemplateError(AffordanceError):
    """A template file or library is invalid (the message names the file and the key)."""


class SceneError(AffordanceError):
    """A scene or a click is unusable (empty, non-finite, click far from any point...)."""


class RegistrationError(AffordanceError):
    """Fitting could not run (no templates, nothing to fit to)."""


class EngineStateError(AffordanceError):
    """An engine action was asked for at a moment it does not apply (nothing selected...)."""


#: the longest text taken from outside (a name, a frame id, a message) echoed into a log line, a
#: reply or the status
MAX_ECHO = 200


def bounded(text, limit: int = MAX_ECHO) -> str:
    """``text`` as it may be echoed: at most ``limit`` characters, longer text cut and marked
    with its length (so a 10 MB name costs a line, not 10 MB in every later status)."""
    text = str(text)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text):,} characters)"


class FrameError(AffordanceError):
    """No transform is known between two frames (at the time asked for)."""


class FrameNotYet(FrameError):
    """The transform at the time asked for has not arrived yet: the newest one known is
    ``behind`` seconds older."""

    def __init__(self, message: str, behind: float = 0.0):
        super().__init__(message)
        self.behind = float(behind)
