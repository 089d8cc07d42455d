"""--allow-pickle FOLDER grants unpickling for the folder it names and no other."""

from __future__ import annotations

import pytest

from gns_framework.data.pickle_grant import pickle_granted
from gns_framework.errors import DatasetError


def test_the_grant_covers_only_the_folder_it_names(tmp_path):
    data, other = tmp_path / "data", tmp_path / "other"
    assert pickle_granted(data, None) is False
    assert pickle_granted(data, tmp_path / "." / "data") is True
    with pytest.raises(DatasetError, match=f"give --allow-pickle {data} if you trust that one"):
        pickle_granted(data, other)
