#!/usr/bin/env python3
"""Decodes every message of hybsim MCAP files with the official `mcap` reader.

Usage: mcap_check.py FILE.mcap...

For each file: reads the summary, then every message in file order; checks
that each channel's schema is a JSON Schema (`jsonschema`), that each
message is one JSON object with the schema's required keys, and prints one
JSON line per file: {"file", "messages": {topic: count}, "schemas": [...]}.
Exits 1 (with the reason on stderr) at the first message that does not
decode.
"""
import json
import sys

from mcap.reader import make_reader


def check(path):
    counts = {}
    schemas = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is None or schema.encoding != "jsonschema":
                raise SystemExit(f"{path}: channel {channel.topic} has no JSON Schema")
            if channel.message_encoding != "json":
                raise SystemExit(f"{path}: channel {channel.topic} is not JSON")
            if schema.id not in schemas:
                schemas[schema.id] = json.loads(schema.data)
            try:
                payload = json.loads(message.data)
            except ValueError as e:
                raise SystemExit(
                    f"{path}: message {message.sequence} on {channel.topic} does not decode: {e}"
                )
            if not isinstance(payload, dict):
                raise SystemExit(f"{path}: message on {channel.topic} is not an object")
            missing = [k for k in schemas[schema.id].get("required", []) if k not in payload]
            if missing:
                raise SystemExit(f"{path}: message on {channel.topic} lacks {missing}")
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    print(json.dumps({"file": path, "messages": counts,
                      "schemas": sorted(s.get("title", "") for s in schemas.values())}))


if __name__ == "__main__":
    for p in sys.argv[1:]:
        check(p)
