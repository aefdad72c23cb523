"""What an ONNX file asks to read besides itself: the external-data files its tensors point to.

A bundle's graphs must be self-contained. onnxruntime resolves an external-data `location` against the model's
folder (or, for a model handed over as bytes, the process's working folder) and reads it, so a graph could pull in a
file that the manifest never listed and no hash covers. The runtime has no `onnx` package, so this walks the
protobuf wire format itself, through every place a tensor can sit: initializers, sparse initializers, node
attributes (tensors and subgraphs, recursively), functions and training info. Field numbers are onnx.proto3's.
"""
from __future__ import annotations

# (message, field number) -> the message type of that length-delimited field, for the fields that can hold tensors
_CHILDREN = {
    ("model", 7): "graph", ("model", 20): "training", ("model", 25): "function",
    ("training", 1): "graph", ("training", 2): "graph",
    ("graph", 1): "node", ("graph", 5): "tensor", ("graph", 15): "sparse",
    ("function", 7): "node",
    ("node", 5): "attribute",
    ("attribute", 5): "tensor", ("attribute", 6): "graph", ("attribute", 10): "tensor", ("attribute", 11): "graph",
    ("attribute", 22): "sparse", ("attribute", 23): "sparse",
    ("sparse", 1): "tensor", ("sparse", 2): "tensor",
    ("tensor", 13): "entry",
}
_TENSOR_DATA_LOCATION, _EXTERNAL = 14, 1
_MAX_DEPTH = 64


class ProtobufError(ValueError):
    """The bytes are not a well-formed protobuf message."""


def external_data(data: bytes) -> list[str]:
    """The `location` of every tensor stored outside the file (empty for a self-contained model); a tensor marked
    EXTERNAL without a location is listed as ''. Raises ProtobufError for bytes that are not a protobuf message."""
    found: list[str] = []
    _walk(memoryview(data), "model", found, 0)
    return found


def _walk(buf: memoryview, kind: str, found: list[str], depth: int) -> None:
    if depth > _MAX_DEPTH:
        raise ProtobufError(f"messages nested more than {_MAX_DEPTH} deep")
    external = located = False
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
            if kind == "tensor" and field == _TENSOR_DATA_LOCATION and value == _EXTERNAL:
                external = True
        elif wire == 1:
            i += 8
        elif wire == 5:
            i += 4
        elif wire == 2:
            length, i = _varint(buf, i)
            if i + length > n:
                raise ProtobufError("a field runs past the end of its message")
            body = buf[i:i + length]
            i += length
            child = _CHILDREN.get((kind, field))
            if child == "entry":
                k, v = _entry(body)
                if k == "location":
                    found.append(v or "")
                    located = True
            elif child is not None:
                _walk(body, child, found, depth + 1)
        else:
            raise ProtobufError(f"wire type {wire} is not used by ONNX files")
        if i > n:
            raise ProtobufError("a field runs past the end of its message")
    if external and not located:
        found.append("")


def _entry(buf: memoryview) -> tuple[str | None, str | None]:
    """A StringStringEntryProto: (key, value)."""
    key = value = None
    i, n = 0, len(buf)
    while i < n:
        tag, i = _varint(buf, i)
        if tag & 7 != 2:
            raise ProtobufError("a string entry holds a field that is not a string")
        length, i = _varint(buf, i)
        text = bytes(buf[i:i + length]).decode("utf-8", "replace")
        i += length
        if tag >> 3 == 1:
            key = text
        elif tag >> 3 == 2:
            value = text
    if i > n:
        raise ProtobufError("a string entry runs past its end")
    return key, value


def _varint(buf: memoryview, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if i >= len(buf) or shift > 63:
            raise ProtobufError("a number runs past the end of its message")
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, i
        shift += 7
