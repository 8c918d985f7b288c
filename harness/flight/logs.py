"""Evaluation logs: one MCAP file per evaluation, read back with the mcap library."""

from __future__ import annotations

import functools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import orjson
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from harness.errors import InfrastructureError, InputError, Problem
from sim_bridge.spec import SpecError, WorldSpec

MCAP_MAGIC = b"\x89MCAP0\r\n"


def slug(text: str) -> str:
    """A file-name and test-id safe form of text: a scenario's name may hold anything, but a
    path with ':' or a space breaks PX4's start-up script (it sources files by path)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "scenario"


@dataclass(frozen=True)
class Truncation:
    """Where a log that was cut short (a flight killed mid-way, a full disk) stops being readable."""

    readable_bytes: int
    size_bytes: int
    last_time_s: float | None

    def describe(self) -> str:
        last = f", last message at t={self.last_time_s:.3f} s" if self.last_time_s is not None else ", no message before it"
        return f"truncated: readable up to byte {self.readable_bytes} of {self.size_bytes}{last}"


@dataclass(frozen=True)
class _Salvage:
    """What a streaming pass read from a file without an intact summary, up to the damage."""

    truncation: Truncation
    channels: dict[int, tuple[str, str | None, str]]  # id -> topic, schema name, encoding
    messages: list[tuple[str, int, bytes]]  # topic, log time ns, data; in log-time order
    metadata: dict[str, dict[str, str]]


def _check_magic(path: Path) -> None:
    with open(path, "rb") as stream:
        start = stream.read(len(MCAP_MAGIC))
    if start != MCAP_MAGIC:
        raise InputError([Problem(str(path), "", "not an MCAP file (it does not start with MCAP's magic bytes): give an evaluation log, a *.mcap "
                                                  "file from a campaign's logs folder or `stella run --out`")])


def _intact(path: Path) -> bool:
    """Whether the file ends as a finished MCAP does (footer and magic) and its summary reads."""
    with open(path, "rb") as stream:
        stream.seek(0, 2)
        if stream.tell() < 2 * len(MCAP_MAGIC):
            return False
        stream.seek(-len(MCAP_MAGIC), 2)
        if stream.read() != MCAP_MAGIC:
            return False
        stream.seek(0)
        try:
            return make_reader(stream).get_summary() is not None
        except (McapError, ValueError, EOFError):
            return False


@functools.lru_cache(maxsize=4)
def _salvage(path: str, _mtime_ns: int, size: int) -> _Salvage:
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str | None, str]] = {}
    found: list[tuple[str, int, bytes]] = []
    found_metadata: dict[str, dict[str, str]] = {}
    readable = 0
    with open(path, "rb") as stream:
        try:
            for record in StreamReader(stream, emit_chunks=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, schemas.get(record.schema_id), record.message_encoding)
                elif isinstance(record, Message) and record.channel_id in channels:
                    found.append((channels[record.channel_id][0], record.log_time, record.data))
                elif isinstance(record, Metadata):
                    found_metadata[record.name] = dict(record.metadata)
                readable = stream.tell()
        except (McapError, ValueError, EOFError):
            pass  # the damage: everything before it has been read
    found.sort(key=lambda entry: entry[1])
    last = found[-1][1] / 1e9 if found else None
    return _Salvage(Truncation(readable, size, last), channels, found, found_metadata)


def _salvaged(path: Path) -> _Salvage | None:
    """None for an intact log; for a damaged one, what could be read of it."""
    _check_magic(path)
    if _intact(path):
        return None
    status = path.stat()
    return _salvage(str(Path(path).resolve()), status.st_mtime_ns, status.st_size)


def truncation(path: Path) -> Truncation | None:
    salvage = _salvaged(path)
    return salvage.truncation if salvage else None


def messages(path: Path, topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, decoded JSON) in log-time order; of a truncated log, what precedes the damage."""
    salvage = _salvaged(path)
    if salvage is not None:
        wanted = None if topics is None else set(topics)
        for topic, time_ns, data in salvage.messages:
            if wanted is None or topic in wanted:
                yield topic, time_ns, json.loads(data)
        return
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            yield channel.topic, message.log_time, json.loads(message.data)


def first_event_s(path: Path, event: str) -> float | None:
    """Simulated time of the log's first /events record of this kind (None: there is none)."""
    return next((m["t"] for _t, _ns, m in messages(path, ["/events"]) if m.get("event") == event), None)


def channels(path: Path) -> list[tuple[int, str, str | None, str]]:
    """(channel id, topic, schema name, message encoding) of every channel the log declares (or, if
    truncated, declared before the damage)."""
    salvage = _salvaged(path)
    if salvage is not None:
        return [(cid, *entry) for cid, entry in salvage.channels.items()]
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    return [(cid, c.topic, summary.schemas[c.schema_id].name if c.schema_id in summary.schemas else None, c.message_encoding)
            for cid, c in summary.channels.items()]


def metadata(path: Path) -> dict[str, dict[str, str]]:
    salvage = _salvaged(path)
    if salvage is not None:
        return salvage.metadata
    with open(path, "rb") as stream:
        return {record.name: dict(record.metadata) for record in make_reader(stream).iter_metadata()}


def json_metadata(path: Path, name: str) -> Any:
    entry = metadata(path).get(name)
    return None if entry is None else json.loads(entry["json"])


def world_of(path: Path) -> WorldSpec | None:
    """The world spec the flight of this log was simulated in (None when the log has none)."""
    document = json_metadata(path, "world")
    if document is None:
        return None
    try:
        return WorldSpec.from_dict(document)
    except SpecError as error:
        raise InputError([Problem(str(path), f"metadata world{error.pointer}", error.message)]) from None


class Recording:
    """An intact log read once, its messages kept undecoded: the simulator's recording, scored and
    then written out as the evaluation's log without reading the file again."""

    def __init__(self, path: Path):
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            try:
                self.summary = reader.get_summary()
            except (McapError, ValueError, EOFError) as error:
                raise InfrastructureError(f"the simulator's log {path} is not a finished MCAP file: {error}") from None
            if self.summary is None:
                raise InfrastructureError(f"the simulator's log {path} has no summary: it was not finished")
            self.metadata = [(record.name, dict(record.metadata)) for record in reader.iter_metadata()]
            in_file_order = [message for _schema, _channel, message in reader.iter_messages(log_time_order=False)]
        # The order mcap's reader gives: log time, ties in file order (the sort is stable).
        self.messages_in_order: list[Message] = sorted(in_file_order, key=lambda message: message.log_time)
        self._topics = {cid: channel.topic for cid, channel in self.summary.channels.items()}

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """(topic, log time ns, decoded JSON) of these topics, in log-time order (as `messages`)."""
        wanted = {cid for cid, topic in self._topics.items() if topic in topics}
        # orjson: the same values as json.loads at a third of its time. The simulator writes with
        # orjson, so a fresh recording holds no NaN or Infinity tokens, which orjson would refuse.
        for message in self.messages_in_order:
            if message.channel_id in wanted:
                yield self._topics[message.channel_id], message.log_time, orjson.loads(message.data)


def merge(recording: Recording, out: Path, *, api_records: Sequence[tuple[int, str, bytes]], extra_metadata: Mapping[str, Any]) -> None:
    """The evaluation's log: the bridge's recording plus the API link's traffic and the harness's metadata.
    A merge that fails (a full disk) leaves no half-written log behind."""
    try:
        _merge(recording, out, api_records, extra_metadata)
    except BaseException:
        Path(out).unlink(missing_ok=True)
        raise


def _merge(recording: Recording, out: Path, api_records: Sequence[tuple[int, str, bytes]], extra_metadata: Mapping[str, Any]) -> None:
    summary = recording.summary
    with open(out, "wb") as target:
        writer = Writer(target, compression=CompressionType.ZSTD)
        writer.start(profile="", library="stella-uav")
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in summary.channels.items()
        }
        # Metadata first: a log cut short later still says what was flown and how it was scored.
        for name, values in recording.metadata:
            if name not in extra_metadata:
                writer.add_metadata(name, values)
        for name, value in extra_metadata.items():
            writer.add_metadata(name, {"json": json.dumps(value)})
        api_channel = next((channel_ids[cid] for cid, c in summary.channels.items() if c.topic == "/mavlink/api"), None)
        for message in recording.messages_in_order:
            writer.add_message(channel_ids[message.channel_id], log_time=message.log_time, data=message.data, publish_time=message.publish_time,
                               sequence=message.sequence)
        if api_channel is not None:
            for time_ns, direction, datagram in api_records:
                data = json.dumps({"link": "api", "direction": direction, "hex": datagram.hex()}).encode()
                writer.add_message(api_channel, log_time=time_ns, data=data, publish_time=time_ns)
        writer.finish()
