#!/usr/bin/env python3
"""Checks a Foresight run recording (MCAP) with an independent reader: the `mcap` Python
package reads the file record by record and `mcap-ros2-support` decodes every message's CDR
bytes against the schema stored in the file (so a schema that does not match its bytes fails).

Checks: profile `ros2`; every channel `cdr` with a `ros2msg` schema; the expected topics
present with more than `--min-count` messages; log time never going back within a channel;
with a summary (a cleanly closed file), its per-channel counts equal what was read. With
`--allow-truncated` a file without summary/footer (a killed recorder) is accepted if it ends
at a record boundary.

Prints one JSON object (topics, counts, schemas, whether the footer was there) and exits 0
when every check passes, 1 otherwise (the failures are listed under "errors").

    check_mcap.py runs/latest/run.mcap --topic /joint_states --topic /tf
"""

import argparse
import json
import os
import sys

from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Channel, Footer, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory


def read_linear(path):
    """Every record up to the footer or the end of the file; returns (records, ended_cleanly)."""
    records = []
    with open(path, "rb") as f:
        reader = StreamReader(f, validate_crcs=True)
        try:
            for r in reader.records:
                records.append(r)
        except EndOfFile:
            # No footer: the file ends after its last complete record, or inside one.
            return records, False, f.tell()
    return records, True, None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mcap")
    ap.add_argument("--topic", action="append", default=[], help="a topic that must have messages")
    ap.add_argument("--min-count", type=int, default=1, help="least messages per --topic")
    ap.add_argument("--allow-truncated", action="store_true", help="accept a file without footer")
    args = ap.parse_args()

    errors = []
    size = os.path.getsize(args.mcap)
    try:
        records, footer, _ = read_linear(args.mcap)
    except McapError as e:
        print(json.dumps({"file": args.mcap, "errors": [f"unreadable: {e!r}"]}))
        return 1

    headers = [r for r in records if isinstance(r, Header)]
    if not headers or headers[0].profile != "ros2":
        errors.append(f"header profile is not ros2: {headers[:1]}")
    schemas = {r.id: r for r in records if isinstance(r, Schema)}
    channels = {}
    for r in records:
        if isinstance(r, Channel):
            channels[r.id] = r
            s = schemas.get(r.schema_id)
            if s is None:
                errors.append(f"{r.topic}: no schema {r.schema_id}")
            elif s.encoding != "ros2msg" or not s.data:
                errors.append(f"{r.topic}: schema {s.name} encoding {s.encoding!r}, {len(s.data)} bytes")
            if r.message_encoding != "cdr":
                errors.append(f"{r.topic}: message encoding {r.message_encoding!r}")

    decoders = DecoderFactory()
    per_topic = {}
    last_time = {}
    for r in records:
        if not isinstance(r, Message):
            continue
        ch = channels.get(r.channel_id)
        if ch is None:
            errors.append(f"message on unknown channel {r.channel_id}")
            continue
        t = per_topic.setdefault(ch.topic, {"count": 0, "schema": schemas[ch.schema_id].name})
        t["count"] += 1
        if r.log_time < last_time.get(ch.topic, 0):
            errors.append(f"{ch.topic}: log time goes back at message {t['count']}")
        last_time[ch.topic] = r.log_time
        decode = decoders.decoder_for(ch.message_encoding, schemas[ch.schema_id])
        try:
            decode(r.data)
        except Exception as e:  # noqa: BLE001 - any decoding failure is a finding
            if t.get("decode_errors", 0) == 0:
                errors.append(f"{ch.topic}: message does not decode with its schema: {e!r}")
            t["decode_errors"] = t.get("decode_errors", 0) + 1

    for topic in args.topic:
        n = per_topic.get(topic, {}).get("count", 0)
        if n < args.min_count:
            errors.append(f"{topic}: {n} message(s), expected at least {args.min_count}")

    if footer:
        with open(args.mcap, "rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None or summary.statistics is None:
            errors.append("closed file without summary statistics")
        else:
            for cid, n in summary.statistics.channel_message_counts.items():
                topic = channels[cid].topic
                got = per_topic.get(topic, {}).get("count", 0)
                if got != n:
                    errors.append(f"{topic}: summary says {n} messages, read {got}")
    elif not args.allow_truncated:
        errors.append("no footer: the file was not closed")

    print(
        json.dumps(
            {
                "file": args.mcap,
                "bytes": size,
                "footer": footer,
                "messages": sum(t["count"] for t in per_topic.values()),
                "topics": per_topic,
                "errors": errors,
            },
            indent=1,
            sort_keys=True,
        )
    )
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
