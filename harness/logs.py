"""Evaluation logs: one MCAP file per evaluation, read back with the mcap library."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer


def slug(text: str) -> str:
    """A file-name and test-id safe form of text: a scenario's name may hold anything, but a
    path with ':' or a space breaks PX4's start-up script (it sources files by path)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "scenario"


def messages(path: Path, topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, decoded JSON) in log-time order."""
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            yield channel.topic, message.log_time, json.loads(message.data)


def metadata(path: Path) -> dict[str, dict[str, str]]:
    with open(path, "rb") as stream:
        return {record.name: dict(record.metadata) for record in make_reader(stream).iter_metadata()}


def json_metadata(path: Path, name: str) -> Any:
    entry = metadata(path).get(name)
    return None if entry is None else json.loads(entry["json"])


def merge(bridge_log: Path, out: Path, *, api_records: Sequence[tuple[int, str, bytes]], extra_metadata: Mapping[str, Any]) -> None:
    """The evaluation's log: the bridge's recording plus the API link's traffic and the harness's metadata."""
    with open(bridge_log, "rb") as source, open(out, "wb") as target:
        reader = make_reader(source)
        summary = reader.get_summary()
        writer = Writer(target, compression=CompressionType.ZSTD)
        writer.start(profile="", library="stella-uav")
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in summary.channels.items()
        }
        api_channel = next((channel_ids[cid] for cid, c in summary.channels.items() if c.topic == "/mavlink/api"), None)
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            writer.add_message(channel_ids[channel.id], log_time=message.log_time, data=message.data, publish_time=message.publish_time, sequence=message.sequence)
        if api_channel is not None:
            for time_ns, direction, datagram in api_records:
                data = json.dumps({"link": "api", "direction": direction, "hex": datagram.hex()}).encode()
                writer.add_message(api_channel, log_time=time_ns, data=data, publish_time=time_ns)
        for record in reader.iter_metadata():
            if record.name not in extra_metadata:
                writer.add_metadata(record.name, dict(record.metadata))
        for name, value in extra_metadata.items():
            writer.add_metadata(name, {"json": json.dumps(value)})
        writer.finish()
