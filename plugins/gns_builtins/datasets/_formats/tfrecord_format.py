"""TFRecord files of ``tf.train.SequenceExample`` messages, read and written without TensorFlow.

A TFRecord file is a run of records, each framed as::

    uint64 length | uint32 masked_crc32c(length bytes) | data | uint32 masked_crc32c(data)

(little-endian), where masked_crc = rotate_right(crc32c, 15) + 0xa282ead8. The
data is a protobuf message; the few messages of ``tensorflow/core/example``
needed here are decoded from the protobuf wire format directly::

    SequenceExample { Features context = 1; FeatureLists feature_lists = 2; }
    Features        { map<string, Feature> feature = 1; }
    FeatureLists    { map<string, FeatureList> feature_list = 1; }
    FeatureList     { repeated Feature feature = 1; }
    Feature         { oneof { BytesList bytes_list = 1; FloatList float_list = 2; Int64List int64_list = 3; } }
    BytesList { repeated bytes value = 1; }
    FloatList { repeated float value = 1; }
    Int64List { repeated int64 value = 1; }

A map is a repeated message ``{ key = 1; value = 2; }``.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gns_framework.api import DatasetError

VARINT, FIXED64, LENGTH_DELIMITED, FIXED32 = 0, 1, 2, 5


def _crc32c_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
        table.append(crc)
    return table


_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli) of ``data``; uses ``google-crc32c`` when installed (much faster)."""
    try:
        import google_crc32c
    except ImportError:
        crc = 0xFFFFFFFF
        for byte in data:
            crc = _TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)
        return crc ^ 0xFFFFFFFF
    return int(google_crc32c.value(bytes(data)))


def masked_crc32c(data: bytes) -> int:
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def read_records(path: Path, verify: bool = True) -> Iterator[bytes]:
    """Yield the data of every record; a short or corrupt record is a DatasetError naming its index."""
    from gns_framework.api import check_record_length

    with open(path, "rb") as handle:
        size = os.fstat(handle.fileno()).st_size
        index = 0
        while True:
            header = handle.read(12)
            if not header:
                return
            if len(header) < 12:
                raise DatasetError(f"{path}: record {index}: truncated header")
            length, length_crc = struct.unpack("<QI", header)
            if verify and masked_crc32c(header[:8]) != length_crc:
                raise DatasetError(f"{path}: record {index}: length checksum mismatch (corrupt file?)")
            # Before reading: a length field of 2^40 must not become a 1 TiB allocation.
            check_record_length(f"{path}: record {index}", length, max(0, size - handle.tell() - 4))
            data = handle.read(length)
            footer = handle.read(4)
            if len(data) < length or len(footer) < 4:
                raise DatasetError(f"{path}: record {index}: truncated data")
            if verify and masked_crc32c(data) != struct.unpack("<I", footer)[0]:
                raise DatasetError(f"{path}: record {index}: data checksum mismatch (corrupt file?)")
            yield data
            index += 1


def write_records(path: Path, records: list[bytes]) -> None:
    with open(path, "wb") as handle:
        for data in records:
            length = struct.pack("<Q", len(data))
            handle.write(length + struct.pack("<I", masked_crc32c(length)))
            handle.write(data + struct.pack("<I", masked_crc32c(data)))


def _read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint")
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 10 bytes")


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1  # negative int64 values travel as their two's complement
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _fields(buf: bytes) -> Iterator[tuple[int, int, int | bytes]]:
    """(field number, wire type, value) of every field of a message; unknown fields included."""
    pos = 0
    while pos < len(buf):
        tag, pos = _read_varint(buf, pos)
        number, wire = tag >> 3, tag & 7
        value: int | bytes
        if wire == VARINT:
            value, pos = _read_varint(buf, pos)
        elif wire == FIXED64:
            value, pos = buf[pos : pos + 8], pos + 8
        elif wire == FIXED32:
            value, pos = buf[pos : pos + 4], pos + 4
        elif wire == LENGTH_DELIMITED:
            size, pos = _read_varint(buf, pos)
            if pos + size > len(buf):
                raise ValueError("length-delimited field runs past the message")
            value, pos = buf[pos : pos + size], pos + size
        else:
            raise ValueError(f"unsupported wire type {wire}")
        yield number, wire, value


def _message(value: int | bytes) -> bytes:
    """The bytes of a field that holds a message or a packed list; a varint there is malformed data."""
    if isinstance(value, int):
        raise ValueError("a varint where a length-delimited field is expected")
    return value


def _field(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | LENGTH_DELIMITED) + _varint(len(payload)) + payload


@dataclass(frozen=True)
class Feature:
    """One ``tf.train.Feature``: a list of bytes, float32 or int64 values."""

    kind: str
    values: list[bytes] | np.ndarray

    @classmethod
    def parse(cls, buf: bytes) -> Feature:
        for number, _, payload in _fields(buf):
            if number == 1:
                return cls("bytes", [bytes(v) for n, _, v in _fields(_message(payload)) if n == 1])
            if number == 2:
                floats: list[np.ndarray] = []
                for n, _wire, v in _fields(_message(payload)):
                    if n == 1:
                        floats.append(np.frombuffer(_message(v), dtype="<f4"))
                return cls("float", np.concatenate(floats) if floats else np.zeros(0, np.float32))
            if number == 3:
                ints: list[int] = []
                for n, _wire, v in _fields(_message(payload)):
                    if n != 1:
                        continue
                    if isinstance(v, int):  # wire == VARINT
                        ints.append(v)
                    else:  # packed
                        pos = 0
                        while pos < len(v):
                            value, pos = _read_varint(v, pos)
                            ints.append(value)
                return cls("int64", np.array(ints, dtype=np.uint64).view(np.int64))
        return cls("bytes", [])

    def serialize(self) -> bytes:
        if self.kind == "bytes":
            return _field(1, b"".join(_field(1, v) for v in self.values))
        if self.kind == "float":
            return _field(2, _field(1, np.asarray(self.values, dtype="<f4").tobytes()))
        return _field(3, _field(1, b"".join(_varint(int(v)) for v in self.values)))


@dataclass(frozen=True)
class SequenceExample:
    """A ``tf.train.SequenceExample``: per-example context features and per-step feature lists."""

    context: dict[str, Feature] = field(default_factory=dict)
    feature_lists: dict[str, list[Feature]] = field(default_factory=dict)

    @classmethod
    def parse(cls, buf: bytes) -> SequenceExample:
        context: dict[str, Feature] = {}
        lists: dict[str, list[Feature]] = {}
        for number, _, payload in _fields(buf):
            if number == 1:
                for key, value in _map_entries(_message(payload)):
                    context[key] = Feature.parse(value)
            elif number == 2:
                for key, value in _map_entries(_message(payload)):
                    lists[key] = [Feature.parse(_message(f)) for n, _, f in _fields(value) if n == 1]
        return cls(context, lists)

    def serialize(self) -> bytes:
        context = b"".join(
            _field(1, _field(1, key.encode()) + _field(2, feature.serialize())) for key, feature in self.context.items()
        )
        lists = b"".join(
            _field(1, _field(1, key.encode()) + _field(2, b"".join(_field(1, f.serialize()) for f in features)))
            for key, features in self.feature_lists.items()
        )
        return _field(1, context) + _field(2, lists)


def _map_entries(buf: bytes) -> Iterator[tuple[str, bytes]]:
    """(key, value message) of every entry of a protobuf ``map<string, Message>`` field."""
    for number, _, entry in _fields(buf):
        if number != 1:
            continue
        key, value = "", b""
        for n, _, v in _fields(_message(entry)):
            if n == 1:
                key = bytes(v).decode()
            elif n == 2:
                value = bytes(v)
        yield key, value
