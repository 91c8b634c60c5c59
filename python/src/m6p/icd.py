"""The M6P ICD as data: every node, port and command with its request and reply layouts,
read from ``m6p-twin icd --json`` (format 1). Commands encode from named, typed
arguments, checked against the ICD's ranges, and replies decode into named fields.

The package carries a copy of that description (``m6p/icd.json``); a test of the twin
fails when the copy and ``m6p-twin icd --json`` differ. :meth:`Icd.from_twin` reads it
from a twin binary instead.

Framing (ICD 3.1; INTERPRETATION.md section 2): a request is ``command u8 | data``, a
reply ``command u8 | result u8 | data``, result 1 success and 0 failure (a failure
carries no data). Little-endian, IEEE-754.
"""

from __future__ import annotations

import json
import math
import re
import struct
import subprocess
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from typing import TypedDict, TypeVar, Union

__all__ = [
    "Command",
    "Fields",
    "Icd",
    "IcdError",
    "IcdJson",
    "Leaf",
    "Node",
    "Reply",
    "Value",
    "parse_duration_s",
]

#: The format of ``m6p-twin icd --json`` this module reads.
FORMAT = 1

#: One decoded value of a request or a reply: an integer (the ICD's ``u8`` to ``u64``,
#: ``i8`` to ``i32``), a float (``f32``, ``f64``), text (a text field), bytes (a tail, or
#: data of a variable layout), an array of one of those (a field with a count above 1), a
#: nested layout (:data:`Fields`) or an array of them.
Value = Union[int, float, str, bytes, list[int], list[float], list["Fields"], "Fields"]
#: A decoded layout: each field's value by the field's name, in the ICD's order.
Fields = dict[str, Value]

_Scalar = TypeVar("_Scalar", int, float, str, bytes)
_Number = TypeVar("_Number", int, float)


# ``m6p-twin icd --json``, format 1, as this module reads it.

_FieldJsonKeywords = TypedDict("_FieldJsonKeywords", {"except": list[float]}, total=False)


class _FieldJsonOptional(_FieldJsonKeywords, total=False):
    doc: str
    unit: str
    range: list[float]
    values: dict[str, str]
    bits: dict[str, str]
    text: bool
    fields: list[FieldJson]


class FieldJson(_FieldJsonOptional):
    """One field of a layout (and its optional ``except``, a Python keyword, above)."""

    name: str
    type: str
    count: int
    offset: int
    size: int


class _TailJsonOptional(TypedDict, total=False):
    doc: str


class TailJson(_TailJsonOptional):
    name: str
    min_bytes: int
    max_bytes: int


class _DataJsonOptional(TypedDict, total=False):
    layout: str
    fields: list[FieldJson]
    tail: TailJson
    doc: str


class DataJson(_DataJsonOptional):
    """A request's or a reply's data."""

    min_bytes: int
    max_bytes: int


class _CommandJsonOptional(TypedDict, total=False):
    doc: str
    access: str
    origin: str
    request: DataJson | None
    reply: DataJson | None
    example: str
    refused_when: str


class CommandJson(_CommandJsonOptional):
    id: int
    name: str


class PortJson(TypedDict):
    port: int
    name: str
    commands: list[CommandJson]


class NodeJson(TypedDict):
    name: str
    addrs: list[int]
    ports: list[PortJson]


class _IcdJsonOptional(TypedDict, total=False):
    framing: str


class IcdJson(_IcdJsonOptional):
    """The whole description (``m6p-twin icd --json``)."""

    format: int
    nodes: list[NodeJson]


_STRUCT = {
    "u8": "B",
    "i8": "b",
    "u16": "H",
    "i16": "h",
    "u32": "I",
    "i32": "i",
    "u64": "Q",
    "f32": "f",
    "f64": "d",
}
_LIMITS = {
    "u8": (0, 0xFF),
    "i8": (-0x80, 0x7F),
    "u16": (0, 0xFFFF),
    "i16": (-0x8000, 0x7FFF),
    "u32": (0, 0xFFFF_FFFF),
    "i32": (-0x8000_0000, 0x7FFF_FFFF),
    "u64": (0, 0xFFFF_FFFF_FFFF_FFFF),
    "f32": (-3.4028234663852886e38, 3.4028234663852886e38),
    "f64": (-math.inf, math.inf),
}

_FLOATS = ("f32", "f64")

RESULT_OK = 1
RESULT_FAIL = 0


class IcdError(ValueError):
    """A command or argument the ICD does not allow; ``field`` names the argument (empty
    for the command as a whole)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}" if field else message)
        self.field = field
        self.message = message


_DURATION_TERM = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*([A-Za-z]*)")
_DURATION_UNITS = {"s": 1.0, "ms": 1e-3, "m": 60.0, "min": 60.0, "h": 3600.0, "d": 86400.0}


def parse_duration_s(text: str) -> float:
    """Seconds in a duration as the twin writes them: ``90``, ``90s``, ``100ms``,
    ``10m``, ``2h``, ``1h 30m``."""
    s = text.strip()
    pos, total, terms = 0, 0.0, 0
    while pos < len(s):
        m = _DURATION_TERM.match(s, pos)
        if m is None:
            raise ValueError(f"`{text}` is not a duration (try 90, 90s, 10m, 2h, 1h 30m)")
        value, unit = float(m.group(1)), m.group(2)
        pos = m.end()
        rest = s[pos:].strip()
        if unit == "":
            if terms > 0 or rest:
                raise ValueError(f"`{text}`: a number without a unit among several terms")
            scale = 1.0
        elif unit in _DURATION_UNITS:
            scale = _DURATION_UNITS[unit]
        else:
            raise ValueError(f"unknown unit `{unit}` in `{text}` (use ms, s, m, h or d)")
        total += value * scale
        terms += 1
        while pos < len(s) and s[pos].isspace():
            pos += 1
    if terms == 0:
        raise ValueError(f"`{text}` is not a duration (try 90, 90s, 10m, 2h, 1h 30m)")
    return total


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(x)


@dataclass(frozen=True)
class Field:
    """One field of a layout, as the ICD describes it."""

    name: str
    type: str
    count: int
    offset: int
    size: int
    doc: str = ""
    unit: str | None = None
    range: tuple[float, float] | None = None
    except_: tuple[float, float] | None = None
    values: Mapping[int, str] = field(default_factory=dict)
    bits: Mapping[int, str] = field(default_factory=dict)
    text: bool = False
    fields: tuple[Field, ...] = ()

    @classmethod
    def from_json(cls, j: FieldJson) -> Field:
        return cls(
            name=j["name"],
            type=j["type"],
            count=j["count"],
            offset=j["offset"],
            size=j["size"],
            doc=j.get("doc", ""),
            unit=j.get("unit"),
            range=(j["range"][0], j["range"][1]) if "range" in j else None,
            except_=(j["except"][0], j["except"][1]) if "except" in j else None,
            values={int(k): v for k, v in j.get("values", {}).items()},
            bits={int(k): v for k, v in j.get("bits", {}).items()},
            text=bool(j.get("text", False)),
            fields=tuple(Field.from_json(f) for f in j.get("fields", [])),
        )

    @property
    def item_size(self) -> int:
        return self.size // self.count if self.count else 0

    def accepts(self, x: float) -> bool:
        """Inside the ICD's range and outside its gap."""
        inside = self.range is None or self.range[0] <= x <= self.range[1]
        gap = self.except_ is not None and self.except_[0] <= x <= self.except_[1]
        return inside and not gap

    def range_text(self) -> str | None:
        """``5..=900``, ``0..=3600 except 1..=9``."""
        if self.range is None:
            return None
        s = f"{_fmt(self.range[0])}..={_fmt(self.range[1])}"
        if self.except_ is not None:
            s += f" except {_fmt(self.except_[0])}..={_fmt(self.except_[1])}"
        return s

    def type_text(self) -> str:
        if self.text:
            return f"text of at most {self.size} characters"
        if self.count > 1:
            return f"{self.count} x {self.type}"
        return self.type

    def number(self, v: object) -> int | float:
        """A number for this field from an argument: a number, a bool, a value's name
        (``"nadir"``), a list of bit names for a bit field, or a duration for a field in
        s or ms (``"10m"``)."""
        if isinstance(v, bool):
            return int(v)
        if isinstance(v, (int, float)):
            return v
        if isinstance(v, (list, tuple)) and self.bits:
            mask = 0
            for name in v:
                bit = _by_name(self.bits, name)
                if bit is None:
                    raise ValueError(
                        f"`{name}` is not one of the bits " + ", ".join(self.bits.values())
                    )
                mask |= 1 << bit
            return mask
        if isinstance(v, str):
            k = _by_name(self.values, v)
            if k is not None:
                return k
            scale = {"s": 1.0, "ms": 1000.0}.get(self.unit or "")
            if scale is not None:
                try:
                    return parse_duration_s(v) * scale
                except ValueError:
                    pass
            also = []
            if scale is not None:
                also.append('a duration such as "10m"')
            if self.values:
                also.append("one of " + ", ".join(f'"{n}"' for n in self.values.values()))
            if also:
                raise ValueError(f"`{v}` is not a number or " + " or ".join(also))
            raise ValueError(f"`{v}` is not a number")
        raise ValueError(f"{v!r} is not a number")


def _by_name(names: Mapping[int, str], name: object) -> int | None:
    """The value named ``name``: case aside, and with ``_`` or ``-`` for a space
    (``velocity_pointing``), as the twin takes them."""
    if not isinstance(name, str):
        return None

    def norm(s: str) -> str:
        return s.lower().replace("_", " ").replace("-", " ")

    typed = norm(name)
    for k, n in names.items():
        if norm(n) == typed:
            return k
    return None


@dataclass(frozen=True)
class Tail:
    """Bytes after a layout, to the end of the packet (SETUP's sync message)."""

    name: str
    doc: str
    min_bytes: int
    max_bytes: int


@dataclass(frozen=True)
class Data:
    """A request's or a reply's data: a layout of fields (maybe with a tail), a tail
    alone, nothing, or a variable layout described only in words (``doc``)."""

    min_bytes: int
    max_bytes: int
    layout: str | None = None
    fields: tuple[Field, ...] = ()
    tail: Tail | None = None
    doc: str | None = None

    @classmethod
    def from_json(cls, j: DataJson | None) -> Data:
        if not j:
            return cls(0, 0)
        t = j.get("tail")
        return cls(
            min_bytes=j["min_bytes"],
            max_bytes=j["max_bytes"],
            layout=j.get("layout"),
            fields=tuple(Field.from_json(f) for f in j.get("fields", [])),
            tail=Tail(t["name"], t.get("doc", ""), t["min_bytes"], t["max_bytes"]) if t else None,
            doc=j.get("doc"),
        )

    @property
    def head_bytes(self) -> int:
        return sum(f.size for f in self.fields)

    @property
    def described(self) -> bool:
        """True when the bytes are described field by field (or there are none)."""
        return self.doc is None


@dataclass(frozen=True)
class Leaf:
    """One decoded value: its path (``slots[0].state``), the value, the ICD's name for it
    (a value's or the set bits', ``None`` otherwise), its unit, and whether it is a mask.
    ``str`` gives the twin's one line for it (``gs``, the node consoles' ``tm``): a mask in
    hex with its bits' names (``channels_on 0x1f7 (COMM1, ...)``, ``0x0 (none)``)."""

    path: str
    value: int | float | str
    name: str | None
    unit: str | None
    mask: bool = False

    def __str__(self) -> str:
        mask = self.mask and isinstance(self.value, int)
        s = f"{self.path} {self.value:#x}" if mask else f"{self.path} {self.value}"
        if self.unit:
            s += f" {self.unit}"
        if self.name:
            s += f" ({self.name})"
        elif mask and self.value == 0:
            s += " (none)"
        return s


def _decode_fields(fields: Sequence[Field], b: bytes, base: int) -> Fields:
    out: Fields = {}
    for f in fields:
        at = base + f.offset
        if f.text:
            out[f.name] = bytes(b[at : at + f.size]).split(b"\0", 1)[0].decode("ascii", "replace")
            continue
        starts = [at + i * f.item_size for i in range(f.count)]
        if f.fields:
            records = [_decode_fields(f.fields, b, start) for start in starts]
            out[f.name] = records[0] if f.count == 1 else records
        elif f.type in _FLOATS:
            reals = [float(struct.unpack_from("<" + _STRUCT[f.type], b, i)[0]) for i in starts]
            out[f.name] = reals[0] if f.count == 1 else reals
        else:
            ints = [int(struct.unpack_from("<" + _STRUCT[f.type], b, i)[0]) for i in starts]
            out[f.name] = ints[0] if f.count == 1 else ints
    return out


def _leaves(fields: Sequence[Field], values: Mapping[str, Value], prefix: str) -> Iterator[Leaf]:
    for f in fields:
        v = values[f.name]
        items: Sequence[Value] = v if isinstance(v, list) else [v]
        for i, item in enumerate(items):
            path = prefix + f.name + (f"[{i}]" if isinstance(v, list) else "")
            if isinstance(item, dict):
                yield from _leaves(f.fields, item, path + ".")
                continue
            if isinstance(item, (bytes, list)):
                raise TypeError(f"{path}: {type(item).__name__} where the ICD has {f.type}")
            name, mask = None, False
            if isinstance(item, int) and item in f.values:
                name = f.values[item]
            elif isinstance(item, int) and f.bits:
                set_bits = [n for bit, n in sorted(f.bits.items()) if item >> bit & 1]
                name, mask = (", ".join(set_bits) if set_bits else None), True
            yield Leaf(path, item, name, f.unit, mask)


def _at(fields: Mapping[str, Value], path: str) -> Value:
    """The value at ``path``: field names joined by ``.``, array items as ``[i]``
    (``slots[0].state``)."""
    v: Value | Mapping[str, Value] = fields
    for part in re.findall(r"[^.\[\]]+", path):
        if isinstance(v, Mapping):
            v = v[part]
        elif isinstance(v, list) and part.isdigit():
            v = v[int(part)]
        else:
            raise KeyError(path)
    if isinstance(v, dict) or not isinstance(v, Mapping):
        return v
    return dict(v)


def _as(v: Value, kind: type[_Scalar], path: str) -> _Scalar:
    if isinstance(v, kind):
        return v
    if kind is float and isinstance(v, int):
        return kind(v)
    raise TypeError(f"{path} is {type(v).__name__}, not {kind.__name__}")


@dataclass(frozen=True)
class Reply:
    """A decoded reply: ``ok`` (result 1), its fields (``fields``: each value by its
    field's name, a :data:`Value`: nested layouts as dicts, arrays as lists, text as
    ``str``), its tail's bytes (``tail``), and the data after the result byte (``data``).

    ``reply["current_mode"]`` reads a field (``reply["slots[0].state"]`` one inside a
    nested layout); :meth:`value` and :meth:`array` read one as a given type, for code
    that type-checks; :meth:`name` gives the ICD's name for a value; :meth:`leaves`
    lists every value with its path, name and unit."""

    command: Command
    ok: bool
    data: bytes
    fields: Mapping[str, Value]
    tail: bytes = b""

    def __getitem__(self, path: str) -> Value:
        return _at(self.fields, path)

    def value(self, path: str, kind: type[_Scalar]) -> _Scalar:
        """The value at ``path`` as ``kind``: ``int``, ``float`` (an integer field's value
        is converted), ``str`` (a text field) or ``bytes``; a ``TypeError`` when it is
        something else. ``reply.value("mcu_temp_c", int)``."""
        return _as(_at(self.fields, path), kind, path)

    def array(self, path: str, kind: type[_Number]) -> list[_Number]:
        """The array at ``path`` (a field with a count above 1) as a list of ``kind``,
        ``int`` or ``float``: ``reply.array("panels_w", float)``; a ``TypeError`` when
        it is something else."""
        v = _at(self.fields, path)
        if not isinstance(v, list):
            raise TypeError(f"{path} is {type(v).__name__}, not an array")
        items: Sequence[Value] = v
        return [_as(x, kind, f"{path}[{i}]") for i, x in enumerate(items)]

    def name(self, path: str) -> str | None:
        """The ICD's name for the value at ``path`` (``"detumble"``, ``"COMM1, PC"``)."""
        for leaf in self.leaves():
            if leaf.path == path:
                return leaf.name
        raise KeyError(path)

    def leaves(self) -> list[Leaf]:
        return list(_leaves(self.command.reply.fields, self.fields, ""))

    def __str__(self) -> str:
        if not self.ok:
            return f"{self.command.full_name}: failure"
        parts = [str(leaf) for leaf in self.leaves()]
        if self.command.reply.tail is not None:
            parts.append(f"{self.command.reply.tail.name} {self.tail!r}")
        elif not self.command.reply.described and self.data:
            parts.append(self.data.hex())
        return f"{self.command.full_name}: ok" + ("; " + " | ".join(parts) if parts else "")


@dataclass(frozen=True)
class Command:
    """One command of a node's port."""

    node: Node = field(repr=False, compare=False)
    port: int
    port_name: str
    id: int
    name: str
    doc: str
    access: str
    origin: str
    request: Data
    reply: Data
    example: bytes | None = None
    #: When the node also refuses it (beyond a wrong length, a value out of range and the
    #: access rule), in words; empty when nothing more.
    refused_when: str = ""

    @property
    def full_name(self) -> str:
        """``PC.SETUP``."""
        return f"{self.node.name}.{self.name}"

    @property
    def arguments(self) -> list[str]:
        """The names :meth:`encode` takes, in order."""
        names = [f.name for f in self.request.fields]
        if self.request.tail is not None:
            names.append(self.request.tail.name)
        return names

    def encode(self, **args: object) -> bytes:
        """The request's bytes, ``command | data``, from one argument per field of its
        layout (an array field takes a list, a text field a ``str``) and the tail (bytes
        or text; omitted: empty). Every value is checked against its type and the ICD's
        range; :class:`IcdError` names the argument and the range."""
        if not self.request.described:
            raise IcdError(
                "",
                f"{self.full_name} takes request data of varying length "
                f"({self.request.doc}): give it as bytes with encode_raw()",
            )
        known = self.arguments
        for k in args:
            if k not in known:
                raise IcdError(
                    k,
                    f"{self.full_name} takes no arguments"
                    if not known
                    else f"{self.full_name} has no argument `{k}`: " + ", ".join(known),
                )
        out = bytearray([self.id])
        for f in self.request.fields:
            if f.name not in args:
                r = f.range_text()
                raise IcdError(
                    f.name,
                    f"missing: {self.full_name} needs {f.name} ({f.type_text()}"
                    + (f", {r})" if r else ")"),
                )
            out += _encode_field(f, args[f.name])
        t = self.request.tail
        if t is not None:
            out += _tail_bytes(t, args.get(t.name, b""))
        return bytes(out)

    def encode_raw(self, data: bytes) -> bytes:
        """``command | data`` for data given as bytes (a variable layout), checked only
        against the ICD's length limits."""
        if not self.request.min_bytes <= len(data) <= self.request.max_bytes:
            raise IcdError(
                "",
                f"{self.full_name}: {len(data)} bytes of request data; the ICD allows "
                f"{self.request.min_bytes}..={self.request.max_bytes}",
            )
        return bytes([self.id]) + bytes(data)

    def decode_request(self, packet_data: bytes) -> Fields:
        """The arguments of a request (``command | data``), as :meth:`encode` takes
        them (the tail as bytes; the data of a variable layout as ``data``, bytes);
        ``ValueError`` when it is not this command or its length is wrong."""
        values, tail = _decode_data(self, self.request, packet_data, request=True)
        if self.request.tail is not None:
            values[self.request.tail.name] = tail
        return values

    def decode_reply(self, packet_data: bytes) -> Reply:
        """The reply (``command | result | data``): a failure is ``ok=False``; a success
        of the wrong length is a ``ValueError`` naming the ICD's length."""
        b = bytes(packet_data)
        if len(b) < 2 or b[0] != self.id:
            raise ValueError(f"{self.full_name}: not a reply to command {self.id}: {b[:8].hex()}")
        if b[1] != RESULT_OK:
            return Reply(self, False, b[2:], {})
        values, tail = _decode_data(self, self.reply, b[1:], request=False)
        return Reply(self, True, b[2:], values, tail)

    def reply_bytes(self, ok: bool = True, **values: object) -> bytes:
        """A reply's bytes (``command | result | data``), for a node written in Python:
        the reply's fields as :meth:`encode` takes a request's."""
        if not ok:
            return bytes([self.id, RESULT_FAIL])
        out = bytearray([self.id, RESULT_OK])
        for f in self.reply.fields:
            if f.name not in values:
                raise IcdError(f.name, f"missing: the {self.full_name} reply needs {f.name}")
            out += _encode_field(f, values[f.name], check_range=False)
        t = self.reply.tail
        if t is not None:
            out += _tail_bytes(t, values.get(t.name, b""))
        return bytes(out)


def _tail_bytes(t: Tail, v: object) -> bytes:
    """A tail's bytes from bytes or text, checked against the ICD's length limits."""
    if isinstance(v, str):
        b = v.encode()
    elif isinstance(v, (bytes, bytearray, memoryview)):
        b = bytes(v)
    else:
        raise IcdError(t.name, "bytes or text expected")
    if not t.min_bytes <= len(b) <= t.max_bytes:
        raise IcdError(t.name, f"{len(b)} bytes; the ICD allows {t.min_bytes}..={t.max_bytes}")
    return b


def _encode_field(f: Field, v: object, check_range: bool = True) -> bytes:
    if f.text:
        if not isinstance(v, str):
            raise IcdError(f.name, "text expected")
        b = v.encode("ascii", "replace")
        if len(b) > f.size:
            raise IcdError(f.name, f"at most {f.size} characters")
        return b.ljust(f.size, b"\0")
    if f.fields:
        if isinstance(v, (bytes, bytearray)) and len(v) == f.size:
            return bytes(v)
        raise IcdError(f.name, f"a nested layout: give its {f.size} bytes")
    items: list[object]
    if f.count == 1:
        items = [v]
    elif isinstance(v, (list, tuple)) and len(v) == f.count:
        items = list(v)
    else:
        raise IcdError(f.name, f"an array of {f.count} values expected")
    out = bytearray()
    lo, hi = _LIMITS[f.type]
    for item in items:
        try:
            x = f.number(item)
        except ValueError as e:
            raise IcdError(f.name, str(e)) from None
        if check_range and not f.accepts(x):
            raise IcdError(f.name, f"{_fmt(x)} is outside the ICD's range {f.range_text()}")
        integer = not f.type.startswith("f")
        if integer and not float(x).is_integer():
            raise IcdError(f.name, f"{_fmt(x)} is not a whole number ({f.type})")
        if (isinstance(x, float) and math.isnan(x)) or not lo <= x <= hi:
            raise IcdError(f.name, f"{_fmt(x)} is outside {f.type} ({_fmt(lo)}..={_fmt(hi)})")
        out += struct.pack("<" + _STRUCT[f.type], int(x) if integer else float(x))
    return bytes(out)


def _decode_data(c: Command, d: Data, b: bytes, request: bool) -> tuple[Fields, bytes]:
    """Decode ``x | data`` (x: the command byte of a request, the result of a reply):
    its fields and its tail (empty without one)."""
    what = "request" if request else "reply"
    b = bytes(b)
    if request and (not b or b[0] != c.id):
        raise ValueError(f"{c.full_name}: not command {c.id}: {b[:8].hex()}")
    data = b[1:]
    if not d.min_bytes <= len(data) <= d.max_bytes:
        raise ValueError(
            f"{c.full_name} {what}: {len(data)} data bytes; the ICD says "
            + (f"{d.min_bytes}" if d.min_bytes == d.max_bytes else f"{d.min_bytes}..={d.max_bytes}")
        )
    if not d.described:
        return {"data": data}, b""
    values = _decode_fields(d.fields, data, 0)
    return values, data[d.head_bytes :] if d.tail is not None else b""


@dataclass(frozen=True)
class Node:
    """One node of the ICD: its name, CSP addresses and commands."""

    name: str
    addrs: tuple[int, ...]
    commands: tuple[Command, ...] = field(repr=False, compare=False)

    def command(self, name: str) -> Command:
        for c in self.commands:
            if c.name.lower() == name.lower():
                return c
        raise IcdError(
            "",
            f"the {self.name} has no command `{name}`: " + ", ".join(c.name for c in self.commands),
        )

    @property
    def ports(self) -> dict[int, str]:
        return {c.port: c.port_name for c in self.commands}


class Icd:
    """The ICD: nodes, ports and commands (``m6p-twin icd --json``)."""

    def __init__(self, doc: IcdJson) -> None:
        if doc.get("format") != FORMAT:
            raise ValueError(
                f"ICD description format {doc.get('format')!r}; this package reads format {FORMAT}"
            )
        self.doc = doc
        self.framing: str = doc.get("framing", "")
        nodes = []
        for n in doc["nodes"]:
            commands: list[Command] = []
            node = Node(n["name"], tuple(n["addrs"]), ())
            for p in n["ports"]:
                for c in p["commands"]:
                    ex = c.get("example")
                    commands.append(
                        Command(
                            node=node,
                            port=p["port"],
                            port_name=p["name"],
                            id=c["id"],
                            name=c["name"],
                            doc=c.get("doc", ""),
                            access=c.get("access", "any"),
                            origin=c.get("origin", "icd"),
                            request=Data.from_json(c.get("request")),
                            reply=Data.from_json(c.get("reply")),
                            example=bytes.fromhex(ex) if ex is not None else None,
                            refused_when=c.get("refused_when", ""),
                        )
                    )
            object.__setattr__(node, "commands", tuple(commands))
            nodes.append(node)
        self.nodes: tuple[Node, ...] = tuple(nodes)

    @classmethod
    def load(cls, path: str | None = None) -> Icd:
        """From a file written by ``m6p-twin icd --json``; without a path, the copy this
        package carries."""
        if path is None:
            text = resources.files("m6p").joinpath("icd.json").read_text()
        else:
            with open(path) as f:
                text = f.read()
        return cls(json.loads(text))

    @classmethod
    def from_twin(cls, binary: str | None = None) -> Icd:
        """From a twin binary's ``icd --json`` (default: :func:`m6p.twin.find_binary`)."""
        if binary is None:
            from .twin import find_binary

            binary = find_binary()
        out = subprocess.run([binary, "icd", "--json"], check=True, capture_output=True, text=True)
        return cls(json.loads(out.stdout))

    def node(self, name_or_addr: str | int) -> Node:
        """A node by name (``"PC"``, case-insensitive) or CSP address."""
        for n in self.nodes:
            if isinstance(name_or_addr, int):
                if name_or_addr in n.addrs:
                    return n
            elif n.name.lower() == name_or_addr.lower():
                return n
        raise IcdError(
            "",
            f"no node {name_or_addr!r} in the ICD: " + ", ".join(n.name for n in self.nodes),
        )

    def command(self, name: str) -> Command:
        """A command by its full name: ``"PC.SETUP"``, ``"fc.tmgen"``."""
        node, sep, cmd = name.partition(".")
        if not sep:
            raise IcdError("", f"`{name}`: a command is named NODE.COMMAND (PC.SETUP)")
        return self.node(node).command(cmd)

    def commands(self) -> Iterator[Command]:
        for n in self.nodes:
            yield from n.commands

    def on_port(self, addr: int, port: int, command_id: int) -> Command | None:
        """The command ``command_id`` of the node at ``addr`` on ``port`` (the ICD's
        ports; a run that moves a port is not known here)."""
        for n in self.nodes:
            if addr in n.addrs:
                for c in n.commands:
                    if c.port == port and c.id == command_id:
                        return c
        return None
