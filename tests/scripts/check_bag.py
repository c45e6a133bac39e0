#!/usr/bin/env python3
"""Opens a Foresight run folder as a rosbag2 bag with an independent reader: `rosbags`'
rosbag2 `Reader` reads the folder's `metadata.yaml` and its MCAP storage file and pairs each
metadata topic with its MCAP channel (same name, type, serialization format and offered QoS).

Checks: the folder opens as a bag (metadata version, storage `mcap`); every topic's count in
`metadata.yaml` equals the messages the reader yields for it (so every channel's
`offered_qos_profiles` equals its topic's in `metadata.yaml`: a mismatch yields none); the
total equals `message_count`; with `--transient-local T` / `--volatile T`, topic T offers that
durability (in `metadata.yaml` and in the MCAP channel). With `--metadata-only` only
`metadata.yaml` is read (a killed recording: its MCAP file has no footer, which `rosbags`
needs), and its topics and QoS are reported.

Prints one JSON object (version, storage, state, topics with type, count, messages read,
durability, reliability, depth) and exits 0 when every check passes, 1 otherwise (the failures
are listed under "errors").

    check_bag.py runs/latest --transient-local /robot_description --volatile /joint_states
"""

import argparse
import json
import sys
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import McapReader
from ruamel.yaml import YAML


def qos_report(profiles):
    if not profiles:
        return {"profiles": 0}
    q = profiles[0]
    return {
        "profiles": len(profiles),
        "durability": q.durability.name.lower(),
        "reliability": q.reliability.name.lower(),
        "history": q.history.name.lower(),
        "depth": q.depth,
    }


def read_metadata(folder):
    info = YAML(typ="safe").load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {}
    for t in info["topics_with_message_count"]:
        md = t["topic_metadata"]
        topics[md["name"]] = {
            "type": md["type"],
            "count": t["message_count"],
            **qos_report(parse_qos(md.get("offered_qos_profiles", []))),
        }
    return info, topics


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder")
    ap.add_argument("--transient-local", action="append", default=[], metavar="TOPIC")
    ap.add_argument("--volatile", action="append", default=[], metavar="TOPIC")
    ap.add_argument("--metadata-only", action="store_true", help="read metadata.yaml alone")
    args = ap.parse_args()
    folder = Path(args.folder)
    errors = []

    try:
        info, topics = read_metadata(folder)
    except Exception as e:  # noqa: BLE001 - any failure to read is the finding
        print(json.dumps({"folder": str(folder), "errors": [f"metadata.yaml unreadable: {e!r}"]}))
        return 1
    report = {
        "folder": str(folder),
        "version": info.get("version"),
        "storage": info.get("storage_identifier"),
        "files": info.get("relative_file_paths"),
        "ros_distro": info.get("ros_distro"),
        "state": (info.get("custom_data") or {}).get("foresight_recording"),
        "message_count": info.get("message_count"),
        "topics": topics,
    }

    if not args.metadata_only:
        try:
            with Reader(folder) as reader:
                report["reader_message_count"] = reader.message_count
                read = {c.topic: 0 for c in reader.connections}
                for conn, _t, _data in reader.messages():
                    read[conn.topic] += 1
                for c in reader.connections:
                    t = topics.setdefault(c.topic, {})
                    t["read"] = read[c.topic]
                    if c.msgcount != read[c.topic]:
                        errors.append(f"{c.topic}: metadata.yaml says {c.msgcount} messages, read {read[c.topic]}")
                if sum(read.values()) != reader.message_count:
                    errors.append(f"message_count {reader.message_count}, read {sum(read.values())}")
            # The MCAP channels' own QoS (the ros2 profile's offered_qos_profiles), read alone.
            storage = McapReader(folder / info["relative_file_paths"][0])
            storage.open()
            try:
                for c in storage.connections:
                    topics.setdefault(c.topic, {})["channel"] = qos_report(c.ext.offered_qos_profiles)
            finally:
                storage.close()
        except Exception as e:  # noqa: BLE001 - any failure to open the bag is the finding
            errors.append(f"rosbags cannot read the bag: {e!r}")

    for want, names in (("transient_local", args.transient_local), ("volatile", args.volatile)):
        for name in names:
            t = topics.get(name)
            if t is None:
                errors.append(f"{name}: not in metadata.yaml")
                continue
            if t.get("durability") != want:
                errors.append(f"{name}: metadata.yaml durability {t.get('durability')}, expected {want}")
            if not args.metadata_only and t.get("channel", {}).get("durability") != want:
                errors.append(f"{name}: MCAP channel durability {t.get('channel')}, expected {want}")

    report["errors"] = errors
    print(json.dumps(report, indent=1, sort_keys=True))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
