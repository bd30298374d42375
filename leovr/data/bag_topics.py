"""A ROS bag's topics (type, message count, connections) and the choice of the topic each sensor is read
from: the one named, else the only candidate."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from leovr.data import ros_messages as rm
from leovr.errors import DataError, brief


@dataclass
class BagTopic:
    name: str
    msgtype: str
    count: int
    connections: list[Any] = field(default_factory=list)


def bag_topics(reader: Any) -> dict[str, BagTopic]:
    """The reader's connections gathered by topic."""
    topics: dict[str, BagTopic] = {}
    for c in reader.connections:
        t = topics.setdefault(c.topic, BagTopic(c.topic, c.msgtype, 0))
        t.count += int(c.msgcount)
        t.connections.append(c)
    return topics


def pick_topic(
    path: Path,
    topics: dict[str, BagTopic],
    types: tuple[str, ...],
    named: str | None,
    what: str,
    option: str,
    required: bool = True,
    ambiguous_ok: bool = False,
    salvaged: str = "",
) -> str | None:
    """The topic of one of `types`: the one named, else the only candidate (`salvaged`: where a damaged bag
    stops, said when no candidate is found)."""
    found = sorted(t.name for t in topics.values() if t.msgtype in types and t.count > 0)
    if named is not None:
        if named not in topics:
            raise DataError(path, f"no topic {named} (topics of a {what}: {brief(found, 8) or 'none'})")
        if topics[named].msgtype not in types:
            raise DataError(path, f"topic {named} is a {topics[named].msgtype}, not a {what} ({' or '.join(types)})")
        return named
    if len(found) == 1:
        return found[0]
    if not found:
        if required:
            damaged = f"; {salvaged}" if salvaged else ""
            raise DataError(path, f"no {what} topic ({' or '.join(types)}) in this bag{damaged}")
        return None
    if ambiguous_ok:
        warnings.warn(
            f"{path}: {len(found)} {what} topics ({', '.join(found)}); none used, name one with {option}",
            stacklevel=3,
        )
        return None
    raise DataError(path, f"{len(found)} {what} topics ({', '.join(found)}): choose one with {option}")


def pick_info_topic(path: Path, topics: dict[str, BagTopic], camera: str, named: str | None) -> str | None:
    """The camera's CameraInfo: the one named, the only one, or the one beside the image topic."""
    infos = sorted(t.name for t in topics.values() if t.msgtype == rm.INFO_TYPE and t.count > 0)
    if named is not None or len(infos) <= 1:
        return pick_topic(path, topics, (rm.INFO_TYPE,), named, "camera info", "--camera-info-topic", required=False)
    ns = camera.rsplit("/", 1)[0]
    beside = [t for t in infos if t.rsplit("/", 1)[0] == ns]
    if len(beside) == 1:
        return beside[0]
    raise DataError(path, f"{len(infos)} camera info topics ({', '.join(infos)}): choose one with --camera-info-topic")
