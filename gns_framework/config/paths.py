"""Paths named inside a file (a recipe's ``dataset.path``, an inversion's ``model`` and ``observed.dataset``).

A relative path is read relative to the folder of the file that names it, so a
recipe or inversion config runs the same from any working directory. Files
written before this rule named paths relative to the working directory; such a
path, when nothing exists beside the file but it exists from the working
directory, is still read from there. An absolute path is used as it is. A path
that exists nowhere is kept beside the file (``missing="beside"``: an inversion's
error then names where it was looked for) or as written (``missing="as_named"``:
a recipe whose data is not made yet records its path unchanged, as before).
"""

from __future__ import annotations

import os
from pathlib import Path


def resolve_named_path(named: str | Path, source: str | Path | None, missing: str = "beside") -> Path:
    """``named`` as the file ``source`` means it: beside ``source`` first, then from the working directory.

    The result is relative to the working directory when it lies below it (so
    recorded paths stay short and portable), absolute otherwise.
    """
    path = Path(os.path.expanduser(str(named)))
    if path.is_absolute() or source is None:
        return path
    beside = Path(source).parent / path
    if beside.exists():
        return _short(beside)
    if path.exists() or missing == "as_named":
        return path
    return _short(beside)


def _short(path: Path) -> Path:
    absolute = Path(os.path.abspath(path))
    try:
        return absolute.relative_to(Path.cwd())
    except ValueError:
        return absolute
