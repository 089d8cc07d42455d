"""Names from data are never paths: each becomes one safe file name, and writes are checked to stay in their folder.

Trajectory keys, model labels, recipe names, split names and MLflow experiment
names come from files and arguments that need not be the user's own (a downloaded
dataset, a checkpoint, a recipe), and several commands form file names from them
(``rollouts/<label>/<key>.npz``, ``runs/<name>``, ``mlartifacts/<experiment>``).
A key ``../../x`` or ``/home/user/.bashrc`` must not write there.

- :func:`safe_component` turns any string into one path component: only
  ``A-Z a-z 0-9 _ . -`` (everything else, separators and NUL included, becomes
  ``_``), no leading dot or dash (no hidden files, nothing read as an option), no
  trailing dot or space, not empty, no Windows device name, at most
  :data:`MAX_COMPONENT` characters. A name it had to change gets ``-`` and 8 hex
  digits of the SHA-256 of the original, so two names that clean to the same text
  stay apart and a name always maps to the same file; a name that needs no change
  is kept as it is.
- :func:`unique_components` does that for the names of one folder and makes them
  unique there, case-insensitively (``-2``, ``-3``, ... on a clash).
- :func:`require_component` refuses a name that is not already a safe component
  (for split names, which name files to read).
- :func:`ensure_inside` checks that a path lands inside its output folder once
  ``..`` and symbolic links of its folders are resolved, and raises
  :class:`UnsafePathError` naming both otherwise.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from pathlib import Path

from .errors import GnsError

MAX_COMPONENT = 100
"""Longest component made here: with a suffix (``.npz``, ``_0001.npz``) well under the 255 bytes file systems allow."""

_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")
_WINDOWS_DEVICES = frozenset(
    {"con", "prn", "aux", "nul", *(f"com{i}" for i in range(1, 10)), *(f"lpt{i}" for i in range(1, 10))}
)
_DIGEST = 8


class UnsafePathError(GnsError):
    """A file name made from data, or a path, would land outside the folder it belongs in (or is no file name)."""


def safe_component(text: object, max_length: int = MAX_COMPONENT) -> str:
    """``text`` as one safe file or folder name; unchanged when it already is one (see the module docstring)."""
    if max_length < 2 * _DIGEST:
        raise ValueError(f"max_length {max_length}: at least {2 * _DIGEST}")
    raw = str(text)
    cleaned = _UNSAFE.sub("_", raw).lstrip(".-").rstrip(". ")
    if cleaned.split(".")[0].lower() in _WINDOWS_DEVICES:
        cleaned = "_" + cleaned
    if cleaned and cleaned == raw and len(cleaned) <= max_length:
        return cleaned
    digest = hashlib.sha256(raw.encode("utf-8", "surrogatepass")).hexdigest()[:_DIGEST]
    return f"{(cleaned or 'unnamed')[: max_length - _DIGEST - 1]}-{digest}"


def unique_components(names: Iterable[object], taken: Iterable[str] = (), max_length: int = MAX_COMPONENT) -> list[str]:
    """:func:`safe_component` of each name, unique among themselves and ``taken`` (ignoring case).

    The first of equal names keeps its component; later ones get ``-2``, ``-3``, ...
    (the same name twice is two files, never one overwritten).
    """
    seen = {t.casefold() for t in taken}
    components = []
    for name in names:
        base = safe_component(name, max_length)
        candidate, count = base, 1
        while candidate.casefold() in seen:
            count += 1
            suffix = f"-{count}"
            candidate = base[: max_length - len(suffix)] + suffix
        seen.add(candidate.casefold())
        components.append(candidate)
    return components


def require_component(text: str, what: str) -> str:
    """``text`` when it is a safe component already, else :class:`UnsafePathError` saying what it must be."""
    if not isinstance(text, str) or safe_component(text) != text:
        raise UnsafePathError(
            f"{what} {text!r}: must be a plain name (letters, digits, '_', '.', '-'; not starting with '.' or '-'), "
            "not a path"
        )
    return text


def ensure_inside(path: str | Path, folder: str | Path) -> Path:
    """``path``, after checking it lands inside ``folder``; raises :class:`UnsafePathError` naming both otherwise.

    Both are resolved (``..`` and the symbolic links of existing folders followed),
    except the last component of ``path``: a write replaces a link there, it does not
    follow it. ``path`` must name something below ``folder``, not ``folder`` itself.
    """
    path, folder = Path(path), Path(folder)
    root = folder.resolve()
    target = path.resolve() if path.name in ("", ".", "..") else path.parent.resolve() / path.name
    if target == root or not target.is_relative_to(root):
        raise UnsafePathError(
            f"{path}: would be written outside its output folder {folder} (it resolves to {target}, the folder to "
            f"{root}); names from data become file names inside that folder only"
        )
    return path
