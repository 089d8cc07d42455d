"""The opt-in that lets NumPy unpickle one dataset folder: ``--allow-pickle FOLDER``, for one command.

Datasets are read without unpickling anything (``gns_builtins.datasets._formats.array_pickle``
walks NumPy's pickles of arrays without running them); a pickle naming anything else is
refused unless the user names that very folder on the command line.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import DatasetError


def pickle_granted(folder: Path, allow_pickle: Path | None) -> bool:
    """Whether ``--allow-pickle`` grants unpickling for the dataset in ``folder``.

    The grant names one folder and covers only that folder: one naming another
    folder is an error, so it never applies to data the user did not name (a
    checkpoint's default dataset, say). Recipes and checkpoints never grant it.
    """
    if allow_pickle is None:
        return False
    if Path(allow_pickle).resolve() != Path(folder).resolve():
        raise DatasetError(
            f"--allow-pickle {allow_pickle}: this command reads the dataset in {folder}; the opt-in applies only "
            f"to the folder it names, so give --allow-pickle {folder} if you trust that one"
        )
    return True
