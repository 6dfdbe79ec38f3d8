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
