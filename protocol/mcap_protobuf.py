"""Decode protobuf MCAP messages with the FileDescriptorSet their schema record carries, as Foxglove does:
no generated code, so any file the SDK wrote (and our own ``c2farm.*`` schemas) reads back."""

from __future__ import annotations

from functools import lru_cache

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


@lru_cache(maxsize=64)
def message_class(name: str, descriptor_set: bytes):
    """The message class ``name`` from a serialized FileDescriptorSet (files added dependencies first)."""
    files = list(descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file)
    pool, added = descriptor_pool.DescriptorPool(), set()
    while files:
        ready = [f for f in files if set(f.dependency) <= added]
        if not ready:
            raise ValueError(f"schema {name}: unresolved imports {sorted({d for f in files for d in f.dependency})}")
        for f in ready:
            pool.Add(f)
            added.add(f.name)
        files = [f for f in files if f.name not in added]
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def decode(schema, data: bytes):
    """One message of an MCAP ``schema`` record with ``protobuf`` encoding."""
    if schema is None or schema.encoding != "protobuf":
        raise ValueError(f"not a protobuf schema: {schema and schema.encoding!r}")
    return message_class(schema.name, bytes(schema.data)).FromString(data)
