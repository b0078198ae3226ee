"""Table-driven fixed-layout records (struct formats with named fields) for the binary codecs.

A :class:`Layout` is a list of (name, struct code) in wire order. Decoding a block takes every
field that fits *wholly* in the block (firmware versions differ in how long a leader is) and
keeps any tail it does not understand in ``"_extra"``, so encoding reproduces the block byte for
byte. Array fields use a count prefix (``"4H"``) and come back as tuples.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass


def _is_array(code: str) -> bool:
    """``"4H"`` is an array of 4; ``"8s"`` is one 8-byte string."""
    return len(code) > 1 and code[0].isdigit() and code[-1] not in "sp"


@dataclass(frozen=True)
class Layout:
    """A named struct layout.

    Parameters
    ----------
    name : str
        Block name, used in error messages.
    fields : tuple of (str, str)
        (field name, struct code without byte order), e.g. ``("heading_cdeg", "H")`` or
        ``("range_cm", "4H")`` (tuple-valued).
    order : str
        Byte order prefix for :mod:`struct` (``"<"`` or ``">"``).
    """

    name: str
    fields: tuple[tuple[str, str], ...]
    order: str = "<"

    def __post_init__(self):
        offsets = []
        off = 0
        for fname, code in self.fields:
            size = struct.calcsize(self.order + code)
            offsets.append((fname, code, off, size, _is_array(code)))
            off += size
        object.__setattr__(self, "_items", tuple(offsets))
        object.__setattr__(self, "size", off)
        object.__setattr__(self, "_whole", struct.Struct(
            self.order + "".join(code for _, code in self.fields)))
        # a generated function that builds the dict from the unpacked tuple with one dict
        # display (constant keys): several times faster than a Python loop over the fields
        items = []
        i = 0
        for fname, code in self.fields:
            if _is_array(code):
                n = int(code[:-1])
                items.append(f"{fname!r}: v[{i}:{i + n}]")
                i += n
            else:
                items.append(f"{fname!r}: v[{i}]")
                i += 1
        src = "def _build(v):\n    return {" + ", ".join(items) + "}\n"
        ns: dict = {}
        exec(compile(src, f"<layout {self.name}>", "exec"), ns)  # noqa: S102 - own source
        object.__setattr__(self, "_build", ns["_build"])

    def decode(self, data: bytes | memoryview, offset: int = 0, length: int | None = None
               ) -> dict:
        """Fields of the block ``data[offset:offset+length]`` (all that fit) plus ``_extra``."""
        if length is None:
            length = self.size
        if length >= self.size:
            out = self._build(self._whole.unpack_from(data, offset))
            used = self.size
        else:
            out = {}
            used = 0
            for fname, code, off, size, is_arr in self._items:
                if off + size > length:
                    break
                v = struct.unpack_from(self.order + code, data, offset + off)
                out[fname] = tuple(v) if is_arr else v[0]
                used = off + size
        out["_extra"] = bytes(data[offset + used:offset + length])
        return out

    def encode(self, values: dict) -> bytes:
        """Bytes of a block from the fields present (a prefix of the layout) and ``_extra``."""
        parts = []
        for fname, code, _off, _size, is_arr in self._items:
            if fname not in values:
                break
            v = values[fname]
            try:
                parts.append(struct.pack(self.order + code, *v) if is_arr
                             else struct.pack(self.order + code, v))
            except struct.error as exc:
                raise ValueError(f"{self.name}.{fname}={v!r} does not fit {code!r}: {exc}") \
                    from exc
        parts.append(bytes(values.get("_extra", b"")))
        return b"".join(parts)
