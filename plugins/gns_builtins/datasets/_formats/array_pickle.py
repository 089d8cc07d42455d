"""Reading pickled NumPy object arrays without running any pickle machinery on the file's bytes.

geoelements/gns keeps each trajectory as a NumPy object array of arrays, which
``np.save`` writes as a pickle. Unpickling calls the functions a pickle names with
arguments the file chose, and even an allow-list of NumPy's own globals is no
boundary: ``numpy.dtype('O8')`` with its pickled flags set to 0, then an array
"filled" from raw bytes, hands NumPy pointers the file chose (a segmentation
fault, or worse). So nothing here unpickles. :func:`read_npy_object_array` walks
the pickle's opcodes (lexed by :func:`pickletools.genops`, which only reads) with a
small interpreter of its own that knows the opcodes NumPy's pickles of arrays use
(protocols 2 to 5). The globals those pickles name (:data:`ALLOWED_GLOBALS`) are
never imported or called: a ``REDUCE`` or ``BUILD`` on them is recorded, then
checked, and every array is made from what the checks let through:

- a dtype only from the whitelist :data:`PLAIN_DTYPES` (booleans, integers, floats,
  complex numbers, either byte order), a structured dtype of such fields, or the
  object dtype of the containing arrays; what the file says about the dtype
  (flags, sizes, alignment) must be what NumPy itself writes for it;
- a shape only of non-negative ints, at most :data:`MAX_NDIM` of them, whose
  product (and each of them) is at most :data:`MAX_ELEMENTS`; the byte count must
  be the product times the item size; the order flag C or Fortran;
- every numeric array by ``np.frombuffer(...).reshape(...).copy()``, a NumPy
  scalar by ``np.frombuffer(...)[0]``, an object array by filling an empty one
  element by element; besides those, an object array may hold plain Python
  values (numbers, strings, bytes, lists, tuples, dicts).

Anything else (another global, opcode, argument, state, or a damaged stream) is
refused with an :class:`ArrayPickleError` naming the file, the member, the byte
offset and what was found against what was expected.
"""

from __future__ import annotations

import pickle
import zipfile

import numpy as np

from gns_framework.api import DatasetError, check_zip_member

from .pickle_opcodes import (
    ALLOWED_GLOBALS,
    MAX_ELEMENTS,
    MAX_FIELDS,
    MAX_NDIM,
    MAX_NESTING,
    OBJECT_CODES,
    OPCODES,
    PLAIN_DTYPES,
    Interpreter,
    Refused,
    RefusedName,
)

__all__ = [
    "ALLOWED_GLOBALS",
    "MAX_ELEMENTS",
    "MAX_FIELDS",
    "MAX_NDIM",
    "MAX_NESTING",
    "OBJECT_CODES",
    "OPCODES",
    "PLAIN_DTYPES",
    "ArrayPickleError",
    "RefusedGlobal",
    "read_npy_object_array",
]


class ArrayPickleError(DatasetError):
    """A member of an ``.npz`` is not a pickle of plain NumPy arrays; nothing in it was unpickled.

    Attributes:
        file: the archive, member: the member (the ``.npz`` key), position: byte offset in the
        pickle (None when not about one opcode), found / expected: what the reader saw and wanted.
    """

    def __init__(
        self, file: str, member: str, position: int | None, found: str, expected: str, prefix: str = "refused"
    ):
        self.file, self.member, self.position, self.found, self.expected = file, member, position, found, expected
        where = f"byte {position} of the pickle: " if position is not None else ""
        tail = f"; expected {expected}" if expected else ""
        super().__init__(f"{file}: {member}: {prefix}: {where}{found}{tail}")


class RefusedGlobal(ArrayPickleError, pickle.UnpicklingError):
    """The pickle names a global outside :data:`ALLOWED_GLOBALS`; nothing it names was imported or called."""

    def __init__(self, file: str, member: str, position: int | None, module: str, name: str):
        self.global_name = f"{module}.{name}"
        super().__init__(
            file,
            member,
            position,
            f"refused global {self.global_name}",
            "only numpy.ndarray, numpy.dtype and numpy's multiarray._reconstruct, scalar and numeric._frombuffer",
        )


def read_npy_object_array(archive: zipfile.ZipFile, member: str) -> np.ndarray:
    """The object array in ``member`` (a ``.npy`` file inside an ``.npz``), rebuilt without unpickling.

    The ``.npy`` header (format 1.0 or 2.0, the ones NumPy writes for object
    arrays) gives dtype and shape; the payload is the pickle, read by the
    interpreter described in the module's docstring. Raises :class:`RefusedGlobal`
    for a pickle naming a global outside :data:`ALLOWED_GLOBALS` and
    :class:`ArrayPickleError` (a :class:`~gns_framework.errors.DatasetError`) for
    anything else that is not an object array of plain arrays of the header's
    shape; both name the archive and the member.
    """
    file = str(getattr(archive, "filename", None) or "<archive>")
    key = member[: -len(".npy")] if member.endswith(".npy") else member
    headers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        with archive.open(member) as stream:
            try:
                version = np.lib.format.read_magic(stream)
                if version not in headers:
                    found = f".npy format {version[0]}.{version[1]}"
                    raise ArrayPickleError(file, key, None, found, "1.0 or 2.0 (how NumPy writes object arrays)")
                shape, _, dtype = headers[version](stream)
            except ArrayPickleError:
                raise
            except Exception as exc:  # numpy parses the header as a Python literal: ValueError, SyntaxError, TokenError
                found = f"unreadable .npy header: {type(exc).__name__}: {exc}"
                raise ArrayPickleError(file, key, None, found, "", "not a .npy file") from None
            if dtype != np.dtype(object):
                raise ArrayPickleError(file, key, None, f"the header says dtype {dtype}", "an object array (a pickle)")
            # The stated size bounds what zipfile inflates; checked before a byte of the payload is.
            check_zip_member(f"{file}: {key}", archive.getinfo(member))
            payload = stream.read()
    except KeyError:
        raise ArrayPickleError(file, key, None, f"no member {member!r} in the archive", "") from None
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as exc:
        raise ArrayPickleError(file, key, None, str(exc), "", "truncated or corrupt member") from None
    try:
        array = Interpreter(payload).run()
    except RefusedName as exc:
        raise RefusedGlobal(file, key, exc.position, exc.module, exc.name) from None
    except Refused as exc:
        prefix = "not a numpy object array of arrays (truncated or corrupt?)" if exc.corrupt else "refused"
        raise ArrayPickleError(file, key, exc.position, exc.found, exc.expected, prefix) from None
    promised = f"the header promises an object array of shape {shape}"
    if not isinstance(array, np.ndarray):
        raise ArrayPickleError(file, key, None, f"the pickle holds a {type(array).__name__}", promised)
    if array.dtype != object or array.shape != shape:
        raise ArrayPickleError(file, key, None, f"the pickle holds dtype {array.dtype}, shape {array.shape}", promised)
    return array
