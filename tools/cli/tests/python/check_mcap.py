"""Reads a `conductor record` file with the official MCAP reader and checks it with jsonschema.

Usage: check_mcap.py <file.mcap>
Prints one JSON object: per-channel counts, seq span, time monotonicity, schema checks, metadata.
The Rust test decides what is acceptable.
"""
import json
import sys

import jsonschema
from mcap.reader import make_reader

path = sys.argv[1]
with open(path, "rb") as f:
    reader = make_reader(f)
    header = reader.get_header()
    summary = reader.get_summary()
    channels = {}
    schemas_ok = {}
    validators = {}
    for schema_id, schema in (summary.schemas.items() if summary else []):
        doc = json.loads(schema.data)
        cls = jsonschema.validators.validator_for(doc)
        try:
            cls.check_schema(doc)
            schemas_ok[schema.name] = True
        except jsonschema.SchemaError as e:
            schemas_ok[schema.name] = str(e)
        validators[schema_id] = cls(doc)
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        c = channels.setdefault(channel.topic, {
            "count": 0, "first_seq": None, "last_seq": None, "monotonic": True,
            "invalid": 0, "last_t": None, "schema": schema.name, "encoding": schema.encoding,
            "message_encoding": channel.message_encoding, "metadata": dict(channel.metadata),
            "log_time_is_t_sample": True, "first_t": None,
        })
        body = json.loads(message.data)
        # Every 10th message against the schema (all of them would take seconds).
        if c["count"] % 10 == 0 and not validators[schema.id].is_valid(body):
            c["invalid"] += 1
        if c["last_t"] is not None and message.log_time <= c["last_t"]:
            c["monotonic"] = False
        if abs(body["t_sample"] * 1e9 - message.log_time) > 1e3:
            c["log_time_is_t_sample"] = False
        c["last_t"] = message.log_time
        if c["first_t"] is None:
            c["first_t"] = message.log_time
            c["first_seq"] = body["seq"]
        c["last_seq"] = body["seq"]
        c["count"] += 1
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    print(json.dumps({
        "profile": header.profile,
        "schemas_ok": schemas_ok,
        "channels": channels,
        "metadata": metadata,
        "chunks": len(summary.chunk_indexes) if summary else 0,
        "compression": sorted({c.compression for c in summary.chunk_indexes}) if summary else [],
        "message_indexes": bool(summary and any(c.message_index_offsets for c in summary.chunk_indexes)),
        "statistics": dict(summary.statistics.channel_message_counts) if summary and summary.statistics else {},
    }))
