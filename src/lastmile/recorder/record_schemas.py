"""The documented JSON schemas of our own channels (``lastmile.<Class>``), made from the message classes.

A channel Foxglove has no schema for carries the lossless JSON of one frozen message class of
``lastmile.core`` (see ``mcap_codec.py`` for the encoding). Its schema is generated from that class:
every field with its JSON type and the description the class's docstring gives it, so the file
documents itself and a generic tool (Foxglove's raw-message panel, ``jsonschema``) can check it.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import re
import types
import typing
from enum import Enum
from typing import Any

import numpy as np

ARRAY_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "A NumPy array: little-endian bytes in base64, NumPy dtype string, shape.",
    "properties": {
        "$array": {"type": "string", "contentEncoding": "base64"},
        "dtype": {"type": "string"},
        "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}},
    },
    "required": ["$array", "dtype", "shape"],
}
FLOAT_SCHEMA: dict[str, Any] = {
    "description": "A float; NaN and infinities (which JSON lacks) as {'$float': 'nan' | 'inf' | '-inf'}.",
    "anyOf": [
        {"type": "number"},
        {
            "type": "object",
            "properties": {"$float": {"enum": ["nan", "inf", "-inf"]}},
            "required": ["$float"],
        },
    ],
}


def _enum_schema(enum: type[Enum]) -> dict[str, Any]:
    return {
        "type": "object",
        "description": f"{enum.__name__}: one of {', '.join(str(e.value) for e in enum)}",
        "properties": {"$enum": {"const": enum.__name__}, "value": {"enum": [e.value for e in enum]}},
        "required": ["$enum", "value"],
    }


def _type_schema(tp: Any, defs: dict[str, Any]) -> dict[str, Any]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return {"anyOf": [_type_schema(a, defs) for a in typing.get_args(tp)]}
    if origin in (tuple, list, typing.Sequence):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return {"type": "array", "items": _type_schema(args[0], defs) if args else {}}
    if origin is dict or tp is dict:
        return {"type": "object"}
    if tp is type(None):
        return {"type": "null"}
    if tp is bool:
        return {"type": "boolean"}
    if tp is int or getattr(tp, "__supertype__", None) is int:  # Stamp is a NewType of int
        return {"type": "integer"}
    if tp is float:
        return FLOAT_SCHEMA
    if tp is str:
        return {"type": "string"}
    if tp is np.ndarray or origin is np.ndarray:
        return ARRAY_SCHEMA
    if isinstance(tp, type) and issubclass(tp, Enum):
        return _enum_schema(tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if tp.__name__ not in defs:
            defs[tp.__name__] = {}  # placeholder first: a class may nest itself
            defs[tp.__name__] = _class_schema(tp, defs)
        return {"$ref": f"#/$defs/{tp.__name__}"}
    return {}


def _field_docs(cls: type) -> dict[str, str]:
    """Descriptions of a Google-style ``Attributes:`` section, by field name."""
    doc = cls.__doc__ or ""
    out: dict[str, str] = {}
    current = ""
    for line in doc.splitlines():
        m = re.match(r"^\s{4,8}(\w+)(?:, \w+)*: (.*)$", line)
        if m:
            current = m.group(1)
            out[current] = m.group(2).strip()
            for other in re.findall(r", (\w+)", line.split(":")[0]):
                out[other] = out[current]
        elif current and line.strip() and line.startswith(" " * 12):
            out[current] += " " + line.strip()
        elif not line.strip():
            current = ""
    return out


def _class_schema(cls: type, defs: dict[str, Any]) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    docs = _field_docs(cls)
    props: dict[str, Any] = {"$type": {"const": cls.__name__}}
    required = ["$type"]
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        prop = dict(_type_schema(hints.get(f.name, Any), defs))
        if f.name in docs:
            prop["description"] = docs[f.name]
        props[f.name] = prop
        required.append(f.name)
    summary = (cls.__doc__ or cls.__name__).strip().split("\n\n")[0]
    return {
        "type": "object",
        "description": " ".join(summary.split()),
        "properties": props,
        "required": required,
    }


@functools.cache
def schema_for(cls: type) -> bytes:
    """The JSON schema (bytes) of the channel that carries messages of ``cls``, title ``lastmile.<Class>``."""
    defs: dict[str, Any] = {}
    doc = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"lastmile.{cls.__name__}",
        "$comment": "lastmile's lossless JSON of a lastmile.core message (see recorder/README.md).",
        **_class_schema(cls, defs),
    }
    if defs:
        doc["$defs"] = defs
    return json.dumps(doc, separators=(",", ":")).encode()
