#!/usr/bin/env python3
"""Decodes every message of hybsim MCAP files with the official `mcap` reader.

Usage: mcap_check.py FILE.mcap...

For each file: reads the summary, then every message in file order, and
decodes it by its channel's encoding: `json` channels (JSON Schema
`jsonschema`) with `json`, checking that each message is one object with
the schema's required keys; `protobuf` channels with the official
`mcap-protobuf-support` decoder (the schema's descriptor set), checking that
each message has every field of its type. Prints one JSON line per file:
{"file", "messages": {topic: count}, "schemas": [...], "encodings": [...]}.
Exits 1 (with the reason on stderr) at the first message that does not
decode.
"""
import json
import sys

from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def json_decoder(path, schema, channel):
    if schema is None or schema.encoding != "jsonschema":
        raise SystemExit(f"{path}: JSON channel {channel.topic} has no JSON Schema")
    required = json.loads(schema.data).get("required", [])

    def decode(data):
        payload = json.loads(data)
        if not isinstance(payload, dict):
            raise ValueError("not an object")
        missing = [k for k in required if k not in payload]
        if missing:
            raise ValueError(f"lacks {missing}")
        return payload

    return decode


def protobuf_decoder(path, schema, channel, factory):
    if schema is None or schema.encoding != "protobuf":
        raise SystemExit(f"{path}: protobuf channel {channel.topic} has no protobuf schema")
    decode_proto = factory.decoder_for("protobuf", schema)
    if decode_proto is None:
        raise SystemExit(f"{path}: no protobuf decoder for {schema.name}")

    def decode(data):
        message = decode_proto(data)
        fields = {f.name for f in message.DESCRIPTOR.fields}
        payload = MessageToDict(message, preserving_proto_field_name=True,
                                always_print_fields_with_no_presence=True)
        missing = sorted(fields - set(payload))
        if missing:
            raise ValueError(f"lacks {missing}")
        return payload

    return decode


def check(path):
    counts = {}
    decoders = {}
    names = set()
    encodings = set()
    factory = DecoderFactory()
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.id not in decoders:
                if channel.message_encoding == "json":
                    decoders[channel.id] = json_decoder(path, schema, channel)
                elif channel.message_encoding == "protobuf":
                    decoders[channel.id] = protobuf_decoder(path, schema, channel, factory)
                else:
                    raise SystemExit(f"{path}: channel {channel.topic} has encoding "
                                     f"{channel.message_encoding!r}")
                names.add(schema.name)
                encodings.add(channel.message_encoding)
            try:
                decoders[channel.id](message.data)
            except Exception as e:  # any decoding failure ends the check
                raise SystemExit(
                    f"{path}: message {message.sequence} on {channel.topic} does not decode: {e}"
                )
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    print(json.dumps({"file": path, "messages": counts, "schemas": sorted(names),
                      "encodings": sorted(encodings)}))


if __name__ == "__main__":
    for p in sys.argv[1:]:
        check(p)
