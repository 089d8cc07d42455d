"""TFRecord framing and the SequenceExample wire format, checked against known bytes."""

from __future__ import annotations

import struct
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gns_builtins.datasets._formats import tfrecord_format as tf
from gns_framework.errors import DatasetError


@pytest.fixture(params=["pure python", "google-crc32c"])
def crc_backend(request, monkeypatch):
    if request.param == "pure python":
        monkeypatch.setitem(sys.modules, "google_crc32c", None)
    else:
        pytest.importorskip("google_crc32c")


def test_crc32c_known_answers(crc_backend):
    # Check values of CRC-32C: the standard "123456789", and RFC 3720 appendix B.4.
    assert tf.crc32c(b"123456789") == 0xE3069283
    assert tf.crc32c(bytes(32)) == 0x8A9136AA
    assert tf.crc32c(b"\xff" * 32) == 0x62A8AB43
    assert tf.crc32c(bytes(range(32))) == 0x46DD794E
    assert tf.crc32c(b"") == 0


def test_features_serialize_to_the_protobuf_wire_format():
    assert tf.Feature("int64", np.array([1])).serialize() == b"\x1a\x03\x0a\x01\x01"
    assert tf.Feature("float", np.array([1.0])).serialize() == b"\x12\x06\x0a\x04\x00\x00\x80\x3f"
    assert tf.Feature("bytes", [b"ab"]).serialize() == b"\x0a\x04\x0a\x02ab"


def test_unpacked_repeated_values_are_read_too():
    # Older writers emit repeated scalars one tag each instead of packed.
    unpacked_ints = b"\x1a\x04\x08\x05\x08\x07"
    np.testing.assert_array_equal(tf.Feature.parse(unpacked_ints).values, [5, 7])
    unpacked_floats = b"\x12\x0a\x0d" + struct.pack("<f", 2.5) + b"\x0d" + struct.pack("<f", -1.0)
    np.testing.assert_array_equal(tf.Feature.parse(unpacked_floats).values, [2.5, -1.0])


@pytest.mark.parametrize("malformed", [b"\x18\x05", b"\x10\x05", b"\x08\x05"], ids=["int64", "float", "bytes"])
def test_a_varint_where_a_list_belongs_is_malformed_data_not_a_crash(malformed):
    # Field 3, 2 or 1 of a Feature holds a list (length-delimited); a varint there is a damaged record,
    # reported as ValueError, which the reader turns into a DatasetError naming file and record.
    with pytest.raises(ValueError, match="varint where a length-delimited field is expected"):
        tf.Feature.parse(malformed)
    with pytest.raises(ValueError, match="varint where a length-delimited field is expected"):
        tf.SequenceExample.parse(b"\x08\x05")


@given(st.lists(st.integers(min_value=-(2**63), max_value=2**63 - 1), max_size=20))
def test_int64_lists_round_trip(values):
    parsed = tf.Feature.parse(tf.Feature("int64", np.array(values, dtype=np.int64)).serialize())
    assert parsed.kind == "int64"
    np.testing.assert_array_equal(parsed.values, np.array(values, dtype=np.int64))


@given(
    st.dictionaries(st.text(min_size=1, max_size=8), st.binary(max_size=40), max_size=4),
    st.lists(st.binary(max_size=40), min_size=1, max_size=6),
)
def test_sequence_examples_round_trip(context, frames):
    example = tf.SequenceExample(
        {k: tf.Feature("bytes", [v]) for k, v in context.items()},
        {"position": [tf.Feature("bytes", [f]) for f in frames]},
    )
    back = tf.SequenceExample.parse(example.serialize())
    assert {k: f.values for k, f in back.context.items()} == {k: [v] for k, v in context.items()}
    assert [f.values for f in back.feature_lists["position"]] == [[f] for f in frames]


def test_records_round_trip_and_corruption_is_located(tmp_path):
    file = tmp_path / "x.tfrecord"
    tf.write_records(file, [b"first", b"second record"])
    assert list(tf.read_records(file)) == [b"first", b"second record"]
    data = bytearray(file.read_bytes())
    data[-6] ^= 0xFF
    file.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"record 1: data checksum mismatch"):
        list(tf.read_records(file))
    assert list(tf.read_records(file, verify=False))[1] != b"second record"
    file.write_bytes(bytes(data[:-3]))
    with pytest.raises(DatasetError, match=r"record 1: truncated data"):
        list(tf.read_records(file, verify=False))
