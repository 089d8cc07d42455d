"""Reading pickled NumPy arrays without running code stored in the file.

geoelements/gns keeps each trajectory as a NumPy object array of arrays, which
``np.save`` writes as a pickle. A pickle names the functions that rebuild its
objects, and unpickling calls them: a hostile file names ``os.system``. The
pickles NumPy writes for arrays name only the globals in :data:`ARRAY_GLOBALS`
(NumPy 1.x under ``numpy.core``, 2.x under ``numpy._core``), so
:class:`ArrayUnpickler`, which resolves those and refuses every other name
before anything is called, reads real files and runs nothing else.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np

from ..errors import DatasetError

_RECONSTRUCT = np.empty(0).__reduce__()[0]
"""``numpy.core.multiarray._reconstruct``: an empty ndarray that the pickle then fills."""
_SCALAR = np.float64(0).__reduce__()[0]
"""``numpy.core.multiarray.scalar``: a NumPy scalar from its dtype and bytes."""

ARRAY_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"): _RECONSTRUCT,
    ("numpy._core.multiarray", "_reconstruct"): _RECONSTRUCT,
    ("numpy.core.multiarray", "scalar"): _SCALAR,
    ("numpy._core.multiarray", "scalar"): _SCALAR,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
}
"""Every global a NumPy pickle of arrays, dtypes and scalars names, by its name under NumPy 1.x and 2.x.

Tuples, lists, numbers and bytes have opcodes of their own and name no global.
They are resolved to this NumPy's objects, so a 1.x file never imports the
deprecated ``numpy.core`` under 2.x.
"""


class RefusedGlobal(pickle.UnpicklingError):
    """The pickle names a global outside :data:`ARRAY_GLOBALS`; nothing it names was called."""

    def __init__(self, module: str, name: str):
        self.global_name = f"{module}.{name}"
        super().__init__(f"refused global {self.global_name}")


class ArrayUnpickler(pickle.Unpickler):
    """Unpickles NumPy arrays, dtypes and scalars (and the tuples and lists holding them) only."""

    def find_class(self, module: str, name: str):
        try:
            return ARRAY_GLOBALS[(module, name)]
        except KeyError:
            raise RefusedGlobal(module, name) from None


def read_npy_object_array(archive: zipfile.ZipFile, member: str) -> np.ndarray:
    """The object array in ``member`` (a ``.npy`` file inside an ``.npz``), rebuilt by :class:`ArrayUnpickler`.

    The ``.npy`` header (format 1.0 or 2.0, the ones NumPy writes for object
    arrays) gives dtype and shape; the payload is the pickle. Raises
    :class:`RefusedGlobal` for a pickle naming anything else and ``ValueError``
    when the header or the unpickled value is not an object array of the header's
    shape; a damaged pickle can fail with any exception of the unpickler.
    """
    headers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    with archive.open(member) as file:
        version = np.lib.format.read_magic(file)
        if version not in headers:
            raise ValueError(f".npy format {version[0]}.{version[1]}: object arrays are written in 1.0 or 2.0")
        shape, _, dtype = headers[version](file)
        if dtype != object:
            raise ValueError(f"expected an object array (a pickle), the header says dtype {dtype}")
        array = ArrayUnpickler(file).load()
    promised = f"the header promises an object array of shape {shape}, the pickle holds"
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{promised} a {type(array).__name__}")
    if array.dtype != object or array.shape != shape:
        raise ValueError(f"{promised} dtype {array.dtype}, shape {array.shape}")
    return array


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
