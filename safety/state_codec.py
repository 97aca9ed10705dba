"""One float vector for an immutable state: how the safety core's states live in a Drake Context.

The pure functions of :mod:`telesmooth.safety` take and return NamedTuples (arrays, numbers,
flags, enums, nested NamedTuples). A Drake LeafSystem keeps its state in the Context as
discrete vectors; :class:`VectorCodec` maps such a NamedTuple to one float vector and back,
field by field in declaration order, from the layout of an example value (so no index
constants are kept by hand). Integers, flags and enum values are stored as floats: exact for
integers below 2⁵³. A round trip ``unpack(pack(x))`` gives x back exactly (a test checks it).
"""

from __future__ import annotations

import enum
from typing import Any, NamedTuple

import numpy as np

__all__ = ["VectorCodec"]


class _Field(NamedTuple):
    name: str
    kind: str          # "array", "bool_array", "int", "float", "bool", "enum", "tuple"
    shape: tuple
    size: int
    codec: Any = None  # nested VectorCodec, or the enum class


class VectorCodec:
    """Packs a NamedTuple (of the example's layout) into a float vector and back.

    Args:
        example: a value of the NamedTuple type whose fields have the shapes every packed value
            will have (arrays keep their shape; nested NamedTuples are packed recursively).

    Raises:
        TypeError: a field of a kind that cannot be stored (e.g. a string).
    """

    def __init__(self, example):
        if not hasattr(example, "_fields"):
            raise TypeError(f"{type(example).__name__} is not a NamedTuple")
        self._type = type(example)
        fields = []
        for name in example._fields:
            value = getattr(example, name)
            if hasattr(value, "_fields"):
                codec = VectorCodec(value)
                fields.append(_Field(name, "tuple", (), codec.size, codec))
            elif isinstance(value, enum.Enum):
                fields.append(_Field(name, "enum", (), 1, type(value)))
            elif isinstance(value, (bool, np.bool_)):
                fields.append(_Field(name, "bool", (), 1))
            elif isinstance(value, (int, np.integer)):
                fields.append(_Field(name, "int", (), 1))
            elif isinstance(value, (float, np.floating)):
                fields.append(_Field(name, "float", (), 1))
            elif isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
                kind = "bool_array" if value.dtype == bool else "array"
                fields.append(_Field(name, kind, value.shape, int(value.size)))
            else:
                raise TypeError(f"{self._type.__name__}.{name} = {value!r}: cannot be stored "
                                "in a float vector")
        self._fields = tuple(fields)
        self.size = sum(field.size for field in fields)

    def field_slice(self, name: str) -> slice:
        """Where the top-level field ``name`` lies in the vector."""
        offset = 0
        for field in self._fields:
            if field.name == name:
                return slice(offset, offset + field.size)
            offset += field.size
        raise KeyError(f"{self._type.__name__} has no field {name!r}")

    def pack(self, value) -> np.ndarray:
        """The vector of ``value`` (float64, length :attr:`size`)."""
        out = np.empty(self.size)
        self._pack_into(value, out, 0)
        return out

    def _pack_into(self, value, out, offset) -> int:
        for field in self._fields:
            item = getattr(value, field.name)
            if field.kind == "tuple":
                field.codec._pack_into(item, out, offset)
            elif field.kind in ("array", "bool_array"):
                item = np.asarray(item)
                if item.shape != field.shape:
                    raise ValueError(f"{self._type.__name__}.{field.name} has shape "
                                     f"{item.shape}; expected {field.shape}")
                out[offset:offset + field.size] = item.ravel()
            else:
                out[offset] = float(item)
            offset += field.size
        return offset

    def unpack(self, vector):
        """The NamedTuple stored in ``vector`` (fresh arrays: the vector is not referenced)."""
        vector = np.asarray(vector, dtype=float)
        if vector.shape != (self.size,):
            raise ValueError(f"state vector has shape {vector.shape}; expected ({self.size},)")
        return self._unpack_from(vector, 0)

    def _unpack_from(self, vector, offset):
        values = {}
        for field in self._fields:
            chunk = vector[offset:offset + field.size]
            if field.kind == "tuple":
                values[field.name] = field.codec._unpack_from(vector, offset)
            elif field.kind == "array":
                values[field.name] = chunk.reshape(field.shape).copy()
            elif field.kind == "bool_array":
                values[field.name] = chunk.reshape(field.shape) > 0.5
            elif field.kind == "int":
                values[field.name] = int(chunk[0])
            elif field.kind == "bool":
                values[field.name] = bool(chunk[0] > 0.5)
            elif field.kind == "enum":
                values[field.name] = field.codec(int(chunk[0]))
            else:
                values[field.name] = float(chunk[0])
            offset += field.size
        return self._type(**values)
