"""Reading a flight record's Foxglove channels with their schemas."""

from __future__ import annotations

import json
from collections import defaultdict

import jsonschema
from mcap_protobuf.decoder import DecoderFactory

from companion.recording.record import read_raw


def decode_all(paths) -> dict[str, list[tuple[float, object]]]:
    """Every message of the records, decoded by its own schema: protobuf with the
    schema's descriptors, JSON validated against the schema's JSON Schema."""
    factory, decoders, out = DecoderFactory(), {}, defaultdict(list)
    for schema, channel, message in read_raw(paths):
        if channel.message_encoding == "protobuf":
            assert schema.encoding == "protobuf"
            dec = decoders.setdefault(channel.id, factory.decoder_for("protobuf", schema))
            assert dec is not None, channel.topic
            obj = dec(message.data)
            assert type(obj).__name__ == schema.name.split(".")[-1]
        else:
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            obj = json.loads(message.data)
            if channel.id not in decoders:
                js = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(js)
                decoders[channel.id] = jsonschema.Draft202012Validator(js)
            decoders[channel.id].validate(obj)
        out[channel.topic].append((message.log_time / 1e9, obj))
    return out
