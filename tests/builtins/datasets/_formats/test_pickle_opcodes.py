"""The opcode interpreter on its own: NumPy's pickle of an object array rebuilt, a foreign global refused unrun.

(Every opcode, dtype, protocol and damaged stream: test_array_pickle.py and its fuzz test, through the reader.)
"""

from __future__ import annotations

import os
import pickle

import numpy as np
import pytest

from gns_builtins.datasets._formats.pickle_opcodes import Interpreter, RefusedName


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_an_object_array_of_arrays_is_rebuilt(protocol):
    array = np.empty(2, dtype=object)
    array[0] = np.arange(6, dtype=np.float32).reshape(3, 2)
    array[1] = np.array([1, 2, 3], dtype=np.int64)
    rebuilt = Interpreter(pickle.dumps(array, protocol=protocol)).run()
    assert rebuilt.dtype == object and rebuilt.shape == (2,)
    for got, want in zip(rebuilt, array, strict=True):
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_a_foreign_global_is_refused_before_anything_runs():
    class Payload:
        def __reduce__(self):
            return (os.system, ("echo ran",))

    with pytest.raises(RefusedName) as info:
        Interpreter(pickle.dumps(Payload(), protocol=2)).run()
    assert info.value.name == "system" and info.value.module in ("posix", "os", "nt")
