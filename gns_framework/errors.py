"""Error types raised on bad input: each names the file and the field at fault."""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from pathlib import Path


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` when a close match exists, else an empty string."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class GnsError(Exception):
    """Base class of every error gns-framework raises on purpose."""


class PluginError(GnsError):
    """A plugin is not a valid plugin, clashes with another, or a component name is unknown."""


class PluginWarning(UserWarning):
    """A plugin was skipped (it failed to load), or ``$GNS_DISABLE_PLUGINS`` names none; ``gns`` shows it as one
    line."""


class RecipeError(GnsError):
    """A recipe (or scene spec) failed validation.

    ``problems`` lists every ``(location, message)`` found in one pass, so the
    user fixes all of them at once.
    """

    def __init__(self, source: str | Path | None, problems: list[tuple[str, str]]):
        self.source = str(source) if source is not None else "<recipe>"
        self.problems = problems
        lines = [f"{self.source}: {len(problems)} problem(s)"]
        lines += [f"  {loc}: {msg}" if loc else f"  {msg}" for loc, msg in problems]
        super().__init__("\n".join(lines))


class DatasetError(GnsError):
    """A dataset file is missing, malformed or inconsistent with its metadata."""


class CheckpointError(GnsError):
    """A checkpoint is missing, truncated, corrupt or belongs to another recipe."""


class RolloutDiverged(GnsError):
    """A rollout produced non-finite positions, or particles left the domain by more than the margin.

    Attributes:
        trajectory: key of the trajectory rolled out.
        step: 0-based rolled-out step (the frame is ``step + C``).
        particles: indices of the offending particles.
        cause: what went wrong, in words.
    """

    def __init__(self, message: str, trajectory: str = "", step: int = -1, particles=(), cause: str = ""):
        self.trajectory = trajectory
        self.step = step
        self.particles = list(particles)
        self.cause = cause
        super().__init__(message)


def located(path: str | Path, field: str | None, message: str) -> str:
    """Format ``file: field: message`` the same way everywhere."""
    return f"{path}: {field}: {message}" if field else f"{path}: {message}"
