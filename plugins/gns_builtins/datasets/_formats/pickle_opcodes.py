"""The opcode interpreter of ``array_pickle.py``: NumPy's pickles of arrays walked without running them.

:func:`pickletools.genops` lexes (it only reads); :class:`Interpreter` keeps the pickle
machine's stack and memo itself and knows only the opcodes of :data:`OPCODES`. The
globals of :data:`ALLOWED_GLOBALS` are never imported or called: a ``REDUCE`` or
``BUILD`` on them is recorded as :class:`Pending`, then checked, and every array is
made from what the checks let through (the rules: ``array_pickle.py``'s docstring).
"""

from __future__ import annotations

import io
import math
import pickletools
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

ALLOWED_GLOBALS: dict[tuple[str, str], str] = {
    ("numpy.core.multiarray", "_reconstruct"): "reconstruct",
    ("numpy._core.multiarray", "_reconstruct"): "reconstruct",
    ("numpy.core.multiarray", "scalar"): "scalar",
    ("numpy._core.multiarray", "scalar"): "scalar",
    ("numpy.core.numeric", "_frombuffer"): "frombuffer",
    ("numpy._core.numeric", "_frombuffer"): "frombuffer",
    ("numpy", "ndarray"): "ndarray",
    ("numpy", "dtype"): "dtype",
    ("_codecs", "encode"): "encode",
    ("__builtin__", "bytes"): "bytes",
    ("builtins", "bytes"): "bytes",
}
"""Every global NumPy's pickles of arrays, dtypes and scalars name (NumPy 1.x ``numpy.core``, 2.x
``numpy._core``; protocol 5's ``_frombuffer``; protocol 2's ``_codecs.encode`` and ``bytes`` for byte
strings), with the role it has here. None of them is imported or called."""

PLAIN_DTYPES = frozenset(
    f"{order}{code}" for code in ("i2", "u2", "i4", "u4", "i8", "u8", "f2", "f4", "f8", "c8", "c16") for order in "<>"
) | {"|b1", "|i1", "|u1"}
"""The dtypes (by ``dtype.str``) an array may have: plain numbers of fixed size, either byte order.
``f16``/``c32`` (long double) is left out: its layout differs between machines."""

OBJECT_CODES = frozenset({"O8", "O4"})
"""How NumPy names the object dtype of the arrays holding arrays (64- and 32-bit machines)."""

MAX_NDIM = 32
"""Most dimensions of an array (NumPy 1.x's limit)."""
MAX_ELEMENTS = 2**40
"""Most elements of one array; its bytes must be in the file anyway."""
MAX_NESTING = 64
"""Deepest nesting of lists, tuples, dicts and arrays in one pickle."""
MAX_FIELDS = 4096
"""Most fields of a structured dtype."""

OPCODES = frozenset(
    {
        "PROTO",
        "FRAME",
        "STOP",
        "GLOBAL",
        "STACK_GLOBAL",
        "SHORT_BINUNICODE",
        "BINUNICODE",
        "BINUNICODE8",
        "SHORT_BINBYTES",
        "BINBYTES",
        "BINBYTES8",
        "BYTEARRAY8",
        "MEMOIZE",
        "BINPUT",
        "LONG_BINPUT",
        "BINGET",
        "LONG_BINGET",
        "MARK",
        "EMPTY_TUPLE",
        "TUPLE",
        "TUPLE1",
        "TUPLE2",
        "TUPLE3",
        "EMPTY_LIST",
        "APPEND",
        "APPENDS",
        "EMPTY_DICT",
        "SETITEM",
        "SETITEMS",
        "NONE",
        "NEWTRUE",
        "NEWFALSE",
        "BININT",
        "BININT1",
        "BININT2",
        "LONG1",
        "BINFLOAT",
        "REDUCE",
        "BUILD",
    }
)
"""The opcodes the interpreter runs: those of NumPy's pickles of arrays (and of the plain Python values,
numbers, strings, bytes, lists, tuples, dicts, an object array may hold). Every other one is refused."""


class Refused(Exception):
    """Raised inside the interpreter; :func:`read_npy_object_array` adds the file and the member."""

    def __init__(self, position: int | None, found: str, expected: str = "", corrupt: bool = False):
        super().__init__(found)
        self.position, self.found, self.expected, self.corrupt = position, found, expected, corrupt


class RefusedName(Exception):
    def __init__(self, position: int | None, module: str, name: str):
        super().__init__(f"{module}.{name}")
        self.position, self.module, self.name = position, module, name


@dataclass(eq=False)
class Global:
    """A global the pickle named: only its role, never the object."""

    role: str
    name: str


@dataclass(eq=False)
class Pending:
    """The result of a ``REDUCE`` that NumPy completes with ``BUILD`` (an array or a dtype): recorded, not run."""

    kind: str
    position: int
    code: str = ""
    value: Any = field(default=None)
    built: bool = False


class Interpreter:
    """Runs the opcodes of :data:`OPCODES` over a pickle, building only plain values and checked arrays."""

    def __init__(self, payload: bytes):
        self.payload = payload
        self.stack: list[Any] = []
        self.marks: list[int] = []
        self.memo: dict[int, Any] = {}
        self.resolved: dict[int, tuple[Any, Any]] = {}
        self.resolving: set[int] = set()
        self.position = 0

    # --- the opcode loop -----------------------------------------------------------------------------------

    def run(self) -> Any:
        ops = pickletools.genops(io.BytesIO(self.payload))
        while True:
            try:
                opcode, arg, position = next(ops)
            except StopIteration:
                raise Refused(self.position, "the pickle ends before its STOP opcode", "", corrupt=True) from None
            except (ValueError, EOFError, OverflowError, MemoryError) as exc:
                raise Refused(self.position, str(exc), "", corrupt=True) from None
            self.position = position if position is not None else self.position
            name = opcode.name
            if name not in OPCODES:
                raise Refused(position, f"opcode {name}", "only the opcodes NumPy's pickles of arrays use")
            if name == "STOP":
                if len(self.stack) != 1 or self.marks:
                    left = f"STOP with {len(self.stack)} values and {len(self.marks)} marks left"
                    raise Refused(position, left, "one value")
                return self.resolve(self.stack.pop(), 0)
            try:
                self.step(name, arg)
            except (TypeError, ValueError, OverflowError, UnicodeError) as exc:
                # The checks below cover what they can; anything they miss is still refused, never run.
                raise Refused(position, f"{name}: {type(exc).__name__}: {exc}") from None

    def step(self, name: str, arg: Any) -> None:
        stack = self.stack
        if name == "PROTO":
            if not 2 <= arg <= 5:
                raise Refused(self.position, f"pickle protocol {arg}", "2 to 5 (what NumPy writes)")
        elif name == "FRAME":
            pass
        elif name == "GLOBAL":
            module, _, attribute = arg.partition(" ")
            stack.append(self.global_(module, attribute))
        elif name == "STACK_GLOBAL":
            attribute, module = self.pop(), self.pop()
            if not isinstance(module, str) or not isinstance(attribute, str):
                raise Refused(self.position, f"STACK_GLOBAL of {_kind(module)} and {_kind(attribute)}", "two strings")
            stack.append(self.global_(module, attribute))
        elif name in ("SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "SHORT_BINBYTES", "BINBYTES", "BINBYTES8"):
            stack.append(arg)
        elif name == "BYTEARRAY8":
            stack.append(bytes(arg))
        elif name == "MEMOIZE":
            self.memo[len(self.memo)] = self.top()
        elif name in ("BINPUT", "LONG_BINPUT"):
            self.memo[arg] = self.top()
        elif name in ("BINGET", "LONG_BINGET"):
            if arg not in self.memo:
                raise Refused(self.position, f"{name} {arg}, which was never stored", "a stored index", corrupt=True)
            stack.append(self.memo[arg])
        elif name == "MARK":
            self.marks.append(len(stack))
        elif name == "EMPTY_TUPLE":
            stack.append(())
        elif name == "TUPLE":
            stack.append(tuple(self.pop_mark()))
        elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
            count = int(name[-1])
            items = [self.pop() for _ in range(count)][::-1]
            stack.append(tuple(items))
        elif name == "EMPTY_LIST":
            stack.append([])
        elif name == "APPEND":
            item = self.pop()
            self.mutable(self.top(), list).append(item)
        elif name == "APPENDS":
            items = self.pop_mark()
            self.mutable(self.top(), list).extend(items)
        elif name == "EMPTY_DICT":
            stack.append({})
        elif name == "SETITEM":
            value, key = self.pop(), self.pop()
            self.mutable(self.top(), dict)[self.key(key)] = value
        elif name == "SETITEMS":
            items = self.pop_mark()
            if len(items) % 2:
                raise Refused(self.position, f"SETITEMS of {len(items)} values", "key-value pairs")
            target = self.mutable(self.top(), dict)
            for key, value in zip(items[::2], items[1::2], strict=True):
                target[self.key(key)] = value
        elif name == "NONE":
            stack.append(None)
        elif name == "NEWTRUE":
            stack.append(True)
        elif name == "NEWFALSE":
            stack.append(False)
        elif name in ("BININT", "BININT1", "BININT2", "LONG1", "BINFLOAT"):
            stack.append(arg)
        elif name == "REDUCE":
            args, function = self.pop(), self.pop()
            stack.append(self.reduce(function, args))
        elif name == "BUILD":
            state = self.pop()
            self.build(self.top(), state)

    # --- the stack -----------------------------------------------------------------------------------------

    def pop(self) -> Any:
        floor = self.marks[-1] if self.marks else 0
        if len(self.stack) <= floor:
            raise Refused(self.position, "an opcode takes a value from an empty stack", "", corrupt=True)
        return self.stack.pop()

    def top(self) -> Any:
        floor = self.marks[-1] if self.marks else 0
        if len(self.stack) <= floor:
            raise Refused(self.position, "an opcode needs a value on an empty stack", "", corrupt=True)
        return self.stack[-1]

    def pop_mark(self) -> list[Any]:
        if not self.marks:
            raise Refused(self.position, "an opcode needs a MARK that was never set", "", corrupt=True)
        start = self.marks.pop()
        items = self.stack[start:]
        del self.stack[start:]
        return items

    def mutable(self, target: Any, kind: type) -> Any:
        if type(target) is not kind:
            raise Refused(self.position, f"adding items to {_kind(target)}", f"a {kind.__name__}")
        if id(target) in self.resolved:
            raise Refused(self.position, f"adding items to a {kind.__name__} already used", "a container filled once")
        return target

    def key(self, key: Any) -> Any:
        if type(key) not in (str, int, bytes, bool, float) and key is not None:
            raise Refused(self.position, f"a dict key of {_kind(key)}", "a string or a number")
        return key

    def global_(self, module: str, name: str) -> Global:
        role = ALLOWED_GLOBALS.get((module, name))
        if role is None:
            raise RefusedName(self.position, module, name)
        return Global(role, f"{module}.{name}")

    # --- values --------------------------------------------------------------------------------------------

    def resolve(self, obj: Any, depth: int) -> Any:
        """``obj`` with every recorded array and dtype replaced by the one built from it (each container once)."""
        if isinstance(obj, Pending):
            if not obj.built:
                raise Refused(self.position, f"{_kind(obj)} is used before its state is set")
            return obj.value
        if isinstance(obj, Global):
            raise Refused(self.position, f"the global {obj.name} itself as a value", "arrays, dtypes, numbers")
        if type(obj) not in (list, tuple, dict):
            return obj
        if depth > MAX_NESTING:
            raise Refused(self.position, f"containers nested deeper than {MAX_NESTING}", "")
        ident = id(obj)
        if ident in self.resolved:
            return self.resolved[ident][1]
        if ident in self.resolving:
            raise Refused(self.position, f"a {type(obj).__name__} that contains itself", "")
        self.resolving.add(ident)
        if type(obj) is dict:
            value: Any = {key: self.resolve(item, depth + 1) for key, item in obj.items()}
        else:
            value = type(obj)(self.resolve(item, depth + 1) for item in obj)
        self.resolving.discard(ident)
        self.resolved[ident] = (obj, value)
        return value

    def reduce(self, function: Any, args: Any) -> Any:
        if not isinstance(function, Global):
            raise Refused(self.position, f"REDUCE calling {_kind(function)}", "one of the allowed globals")
        if type(args) is not tuple:
            raise Refused(self.position, f"REDUCE of {function.name} with {_kind(args)} for arguments", "a tuple")
        role = function.role
        if role == "reconstruct":
            cls = args[0] if args else None
            if not (isinstance(cls, Global) and cls.role == "ndarray" and args[1:] == ((0,), b"b")):
                raise Refused(
                    self.position, f"{function.name}{_show(args)}", "(numpy.ndarray, (0,), b'b'), as NumPy writes it"
                )
            return Pending("array", self.position)
        if role == "dtype":
            if len(args) != 3 or type(args[0]) is not str or args[1] not in (False, 0) or args[2] not in (True, 1):
                raise Refused(self.position, f"numpy.dtype{_show(args)}", "(code, False, True), as NumPy writes it")
            return Pending("dtype", self.position, code=args[0])
        if role == "scalar":
            return self.scalar(args)
        if role == "frombuffer":
            return self.frombuffer(args)
        if role == "encode":
            if len(args) != 2 or type(args[0]) is not str or args[1] not in ("latin1", "latin-1"):
                expected = "(text, 'latin1'): bytes in a protocol-2 pickle"
                raise Refused(self.position, f"_codecs.encode{_show(args)}", expected)
            return args[0].encode("latin-1")
        if role == "bytes":
            if args != ():
                raise Refused(self.position, f"bytes{_show(args)}", "bytes(): the empty bytes of a protocol-2 pickle")
            return b""
        raise Refused(self.position, f"REDUCE calling {function.name}", "_reconstruct, dtype, scalar or _frombuffer")

    def build(self, target: Any, state: Any) -> None:
        if not isinstance(target, Pending):
            raise Refused(self.position, f"BUILD of {_kind(target)}", "an array or a dtype made by REDUCE")
        if target.built:
            raise Refused(self.position, f"a second BUILD of the {target.kind} made at byte {target.position}", "one")
        state = self.resolve(state, 0)
        target.value = self.dtype(target.code, state) if target.kind == "dtype" else self.array_from_state(state)
        target.built = True

    # --- dtypes --------------------------------------------------------------------------------------------

    def dtype(self, code: str, state: Any) -> np.dtype:
        """The dtype that ``numpy.dtype(code)`` with ``state`` stands for, when it is one of those allowed."""
        found = f"numpy.dtype({code!r}) with state {_show(state)}"
        if type(state) is not tuple or len(state) != 8 or state[0] != 3:
            raise Refused(self.position, found, "a version-3 dtype state of 8 items, as NumPy writes it")
        _, order, subarray, names, fields, elsize, alignment, _flags = state
        if subarray is not None:
            raise Refused(self.position, found, "no subarray dtype")
        if code in OBJECT_CODES:
            candidate = np.dtype(object)
        elif names is None and fields is None:
            if order not in ("<", ">", "|"):
                raise Refused(self.position, found, "byte order '<', '>' or '|'")
            text = f"{order}{code}"
            if text not in PLAIN_DTYPES:
                raise Refused(self.position, f"dtype {text!r} ({found})", f"one of {', '.join(sorted(PLAIN_DTYPES))}")
            candidate = np.dtype(text)
        else:
            candidate = self.structured(code, found, names, fields, elsize, alignment)
        expected = candidate.__reduce__()
        # NumPy names the object dtype O8 or O4 by the machine's pointer size; the array is built here either way.
        named = code if code not in OBJECT_CODES else expected[1][0]
        if (named, False, True) != expected[1] or not _same(state, expected[2]):
            wanted = f"numpy.dtype{_show(expected[1])} with state {_show(expected[2])}, as NumPy writes it"
            raise Refused(self.position, found, wanted)
        return candidate

    def structured(self, code: str, found: str, names: Any, fields: Any, elsize: Any, alignment: Any) -> np.dtype:
        ok = (
            type(names) is tuple
            and 0 < len(names) <= MAX_FIELDS
            and all(type(n) is str for n in names)
            and len(set(names)) == len(names)
            and type(fields) is dict
            and set(fields) == set(names)
            and type(elsize) is int
            and 0 < elsize <= 2**20
            and code == f"V{elsize}"
            and type(alignment) is int
        )
        if not ok:
            wanted = f"a structured dtype: names, fields of them, V<itemsize> (at most {MAX_FIELDS} fields)"
            raise Refused(self.position, found, wanted)
        formats, offsets = [], []
        for field_name in names:
            entry = fields[field_name]
            if not (
                type(entry) is tuple and len(entry) == 2 and isinstance(entry[0], np.dtype) and type(entry[1]) is int
            ):
                raise Refused(
                    self.position, f"field {field_name!r}: {_show(entry)}", "(dtype, offset), without a title"
                )
            field_dtype, offset = entry
            if field_dtype.hasobject or field_dtype.subdtype is not None:
                raise Refused(self.position, f"field {field_name!r} of dtype {field_dtype}", "a numeric field")
            if offset < 0 or offset + field_dtype.itemsize > elsize:
                raise Refused(
                    self.position,
                    f"field {field_name!r} at bytes {offset}..{offset + field_dtype.itemsize}",
                    f"within the item's {elsize} bytes",
                )
            formats.append(field_dtype)
            offsets.append(offset)
        return np.dtype(
            {"names": list(names), "formats": formats, "offsets": offsets, "itemsize": elsize}, align=alignment > 1
        )

    # --- arrays --------------------------------------------------------------------------------------------

    def array_from_state(self, state: Any) -> np.ndarray:
        """The array ``ndarray.__setstate__`` would make of ``state``, made here from checked parts."""
        if type(state) is not tuple or len(state) != 5 or state[0] != 1:
            wanted = "(1, shape, dtype, is_fortran, data), as NumPy writes it"
            raise Refused(self.position, f"array state {_show(state)}", wanted)
        _, shape, dtype, fortran, data = state
        shape = self.shape(shape)
        if not isinstance(dtype, np.dtype):
            raise Refused(self.position, f"an array whose dtype is {_kind(dtype)}", "a numpy.dtype")
        if type(fortran) is not bool:
            raise Refused(self.position, f"order flag {_show(fortran)}", "True (Fortran) or False (C)")
        count = math.prod(shape)
        if dtype.hasobject:
            if dtype != np.dtype(object) or type(data) is not list or len(data) != count:
                raise Refused(
                    self.position,
                    f"an object array of shape {shape} with {_kind(data)} for data",
                    f"a list of {count} items",
                )
            return _object_array(data, shape, fortran)
        return self.numeric(data, dtype, shape, "F" if fortran else "C")

    def numeric(self, data: Any, dtype: np.dtype, shape: tuple[int, ...], order: Literal["C", "F"]) -> np.ndarray:
        if type(data) is not bytes:
            raise Refused(self.position, f"a {dtype} array whose data is {_kind(data)}", "bytes")
        if len(data) != math.prod(shape) * dtype.itemsize:
            raise Refused(
                self.position,
                f"{len(data)} bytes of data for a {dtype} array of shape {shape}",
                f"{math.prod(shape)} x {dtype.itemsize} = {math.prod(shape) * dtype.itemsize} bytes",
            )
        return np.frombuffer(data, dtype=dtype).reshape(shape, order=order).copy(order="K")

    def shape(self, shape: Any) -> tuple[int, ...]:
        if (
            type(shape) is not tuple
            or len(shape) > MAX_NDIM
            or not all(type(d) is int and 0 <= d <= MAX_ELEMENTS for d in shape)
            or math.prod(shape) > MAX_ELEMENTS
        ):
            raise Refused(
                self.position,
                f"shape {_show(shape)}",
                f"a tuple of at most {MAX_NDIM} non-negative ints with at most {MAX_ELEMENTS} elements "
                "(each of them too)",
            )
        return shape

    def frombuffer(self, args: tuple) -> np.ndarray:
        """Protocol 5's ``_frombuffer(buffer, dtype, shape, order)``."""
        if len(args) != 4 or args[3] not in ("C", "F"):
            raise Refused(self.position, f"_frombuffer{_show(args)}", "(buffer, dtype, shape, 'C' or 'F')")
        data, dtype, shape, order = (self.resolve(item, 0) for item in args)
        if not isinstance(dtype, np.dtype) or dtype.hasobject:
            raise Refused(self.position, f"_frombuffer of dtype {_show(dtype)}", "a numeric dtype")
        return self.numeric(data, dtype, self.shape(shape), order)

    def scalar(self, args: tuple) -> Any:
        """``numpy.core.multiarray.scalar(dtype, bytes)``: one number."""
        if len(args) != 2:
            raise Refused(self.position, f"scalar{_show(args)}", "(dtype, bytes)")
        dtype, data = (self.resolve(item, 0) for item in args)
        if not isinstance(dtype, np.dtype) or dtype.hasobject:
            raise Refused(self.position, f"a scalar of dtype {_show(dtype)}", "a numeric dtype")
        if type(data) is not bytes or len(data) != dtype.itemsize:
            raise Refused(self.position, f"a {dtype} scalar from {_kind(data)}", f"{dtype.itemsize} bytes")
        return np.frombuffer(data, dtype=dtype)[0]


def _object_array(items: list, shape: tuple[int, ...], fortran: bool) -> np.ndarray:
    """An object array of ``shape`` holding ``items`` in C order (how NumPy pickles them, whatever the layout)."""
    flat = np.empty(len(items), dtype=object)
    for index, item in enumerate(items):
        flat[index] = item
    array = flat.reshape(shape)
    return np.asfortranarray(array) if fortran and array.ndim > 1 else array


def _same(found: Any, expected: Any) -> bool:
    """Whether a state read from the file equals the one NumPy writes (dtypes by equality, exact types otherwise)."""
    if isinstance(expected, np.dtype) or isinstance(found, np.dtype):
        both = isinstance(found, np.dtype) and isinstance(expected, np.dtype)
        return both and found == expected and found.str == expected.str
    if type(expected) in (tuple, list):
        return type(found) is type(expected) and len(found) == len(expected) and all(map(_same, found, expected))
    if type(expected) is dict:
        same_keys = type(found) is dict and found.keys() == expected.keys()
        return same_keys and all(_same(found[k], expected[k]) for k in expected)
    return type(found) is type(expected) and found == expected


def _kind(value: Any) -> str:
    if isinstance(value, Global):
        return f"the global {value.name}"
    if isinstance(value, Pending):
        return f"the {value.kind} made at byte {value.position}"
    return f"a {type(value).__name__}"


def _show(value: Any, limit: int = 160) -> str:
    """A short description of a value from the file, for messages (long bytes and deep nesting cut)."""

    def describe(item: Any, depth: int) -> str:
        if isinstance(item, (Global, Pending)):
            return _kind(item)
        if isinstance(item, np.dtype):
            return f"dtype({item.str!r})"
        if isinstance(item, (bytes, bytearray)):
            return f"<{len(item)} bytes>" if len(item) > 16 else repr(bytes(item))
        if isinstance(item, np.ndarray):
            return f"<{item.dtype} array {item.shape}>"
        if depth > 3:
            return "..."
        if type(item) is tuple:
            inner = ", ".join(describe(x, depth + 1) for x in item[:10]) + (", ..." if len(item) > 10 else "")
            return f"({inner}{',' if len(item) == 1 else ''})"
        if type(item) is list:
            return f"<list of {len(item)}>"
        if type(item) is dict:
            return f"<dict of {len(item)}>"
        text = repr(item)
        return text if len(text) <= 40 else text[:37] + "..."

    text = describe(value, 0)
    return text if len(text) <= limit else text[: limit - 3] + "..."
