"""The one error the scene-format readers raise."""

from __future__ import annotations


class SceneFormatError(ValueError):
    """A scene folder cannot be read: a missing or malformed file, a split the folder cannot
    satisfy, a camera the format cannot describe. The message names the file (or frame) and
    the problem; callers re-raise it as their own typed error (the engine's ``SceneError``,
    the SDK's ``InvalidInput``)."""
