"""What the scans of a damaged bag's storage files collect: the connections they declare and each message's
place in its file (not its data), the error that ends a scan at the damage, and the byte readers the
scanners share."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, BinaryIO


class Truncated(Exception):
    """The file ends (or turns to garbage) inside a record."""


@dataclass
class Connection:
    """What `RosbagSequence` reads of a connection."""

    id: int
    topic: str
    msgtype: str
    msgcount: int = 0


@dataclass
class ScanEntry:
    log_ns: int
    conn: int
    where: tuple  # the storage's own locator of the message's bytes


def read_exact(f: BinaryIO, n: int) -> bytes:
    b = f.read(n)
    if len(b) != n:
        raise Truncated(f"the file ends inside a record ({len(b)} of {n} bytes)")
    return b


def u32(b: bytes, at: int = 0) -> int:
    return struct.unpack_from("<I", b, at)[0]


def u64(b: bytes, at: int = 0) -> int:
    return struct.unpack_from("<Q", b, at)[0]


class Scan:
    """What the scans found, across the bag's storage files."""

    def __init__(self) -> None:
        self.connections: list[Connection] = []
        self.conn_by_file: dict[int, dict[int, int]] = {}  # file, its own id -> index in connections
        self.defs: list[tuple[str, str, str]] = []  # (msgtype, definition, format)
        self.entries: list[ScanEntry] = []
        self.files: list[Any] = []
        self.offset = 0

    def add_connection(self, file: Any, own_id: int, topic: str, msgtype: str, definition: str, fmt: str) -> None:
        from rosbags.typesys.msg import normalize_msgtype

        msgtype = normalize_msgtype(msgtype) if "/msg/" not in msgtype else msgtype
        self.conn_by_file.setdefault(id(file), {})[own_id] = len(self.connections)
        self.connections.append(Connection(len(self.connections), topic, msgtype))
        if definition:
            self.defs.append((msgtype, definition, fmt))

    def add_message(self, file: Any, own_id: int, log_ns: int, where: tuple) -> None:
        conn = self.conn_by_file.get(id(file), {}).get(own_id)
        if conn is None:
            raise Truncated(f"a message of connection {own_id}, which was never declared")
        self.connections[conn].msgcount += 1
        self.entries.append(ScanEntry(log_ns, conn, (len(self.files) - 1, *where)))
