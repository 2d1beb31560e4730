"""Errors the planner core raises on bad input (all TsrrtError subclasses)."""

from __future__ import annotations

from tsrrt_common.errors import TsrrtError


class PlannerError(TsrrtError):
    """Base of every error raised by tsrrt_planner."""


class ObjectiveError(PlannerError):
    """An objective term is malformed: unknown type, bad weight or parameter, no objects."""


class ModelError(PlannerError):
    """A forward model is missing, malformed, or asked for something it cannot predict."""


class ModelFileError(ModelError):
    """A model file is corrupt or does not match the scenario; it is never silently replaced."""


class Cancelled(PlannerError):
    """Work stopped on request (a cancelled goal, a node shutting down) before it had a
    result worth keeping."""
