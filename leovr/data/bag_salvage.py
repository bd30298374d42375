"""The messages of a bag that cannot be opened whole: a recorder killed mid-write leaves a ROS 1 bag
without its index, an MCAP file without its summary (and a ROS 2 bag without metadata.yaml), a SQLite
file cut off inside its pages. Each storage file is scanned from its start, record by record, up to the
first damage; the messages before it are read as from an intact bag (the subset of `rosbags`'
`AnyReader` that `RosbagSequence` uses), and `damaged` says where the scan stopped.

The scan keeps each message's place in the file, not its data: memory stays flat in the bag's length.
Message types come from the definitions the bag carries, else from the standard ROS type store.
"""

from __future__ import annotations

import bisect
import bz2
import sqlite3
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Iterator

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"


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
class _Entry:
    log_ns: int
    conn: int
    where: tuple  # the storage's own locator of the message's bytes


def _read(f: BinaryIO, n: int) -> bytes:
    b = f.read(n)
    if len(b) != n:
        raise Truncated(f"the file ends inside a record ({len(b)} of {n} bytes)")
    return b


def _u32(b: bytes, at: int = 0) -> int:
    return struct.unpack_from("<I", b, at)[0]


def _u64(b: bytes, at: int = 0) -> int:
    return struct.unpack_from("<Q", b, at)[0]


def _decompress(data: bytes, compression: str) -> bytes:
    """A ROS 1 chunk's records (its compressions: none, bz2, lz4)."""
    if compression == "none":
        return data
    if compression == "bz2":
        return bz2.decompress(data)
    if compression == "lz4":
        from lz4.frame import decompress

        return decompress(data)
    raise Truncated(f"unknown chunk compression {compression!r}")


# -- ROS 1 ------------------------------------------------------------------------------------------------


def _ros1_fields(header: bytes) -> dict[str, bytes]:
    fields, at = {}, 0
    while at < len(header):
        n = _u32(header, at)
        name, eq, value = header[at + 4 : at + 4 + n].partition(b"=")
        if at + 4 + n > len(header) or not eq:
            raise Truncated("a record header is malformed")
        fields[name.decode("latin-1")] = value
        at += 4 + n
    return fields


def _ros1_records(buf: bytes) -> Iterator[tuple[dict[str, bytes], int, int]]:
    """(header fields, data offset, data length) of each record in a chunk's bytes."""
    at = 0
    while at < len(buf):
        hlen = _u32(buf, at)
        fields = _ros1_fields(buf[at + 4 : at + 4 + hlen])
        dlen = _u32(buf, at + 4 + hlen)
        start = at + 8 + hlen
        if start + dlen > len(buf):
            raise Truncated("the file ends inside a chunk's record")
        yield fields, start, dlen
        at = start + dlen


class _Ros1File:
    """A ROS 1 bag scanned record by record: bag header, chunks (connections and messages inside),
    index records skipped."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.f = path.open("rb")
        self._chunk: tuple[int, bytes] | None = None

    def scan(self, out: _Scan) -> None:
        if self.f.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
            raise Truncated("not a ROS 1 bag (no '#ROSBAG V2.0' line)")
        size = self.path.stat().st_size
        while True:
            pos = self.f.tell()
            head = self.f.read(4)
            if not head:
                return
            out.offset = pos
            hlen = _u32(head) if len(head) == 4 else 0
            if len(head) < 4 or hlen > 1 << 20:
                raise Truncated("a record header is cut off or malformed")
            fields = _ros1_fields(_read(self.f, hlen))
            dlen = _u32(_read(self.f, 4))
            data_at = self.f.tell()
            op = fields.get("op", b"\0")[0]
            if op == 0x05:  # chunk: its records, decompressed (an uncompressed one cut off: up to the cut)
                data = self.f.read(dlen)
                compression = fields.get("compression", b"none")
                if len(data) < dlen and compression != b"none":
                    raise Truncated("the file ends inside a compressed chunk")
                raw = self._unpack(data, fields) if len(data) == dlen else data
                for rec, start, n in _ros1_records(raw):
                    self._record(rec, raw[start : start + n], (data_at, dlen, compression, start, n), out)
                if len(data) < dlen:
                    raise Truncated("the file ends inside a chunk")
            elif op == 0x07:
                self._record(fields, _read(self.f, dlen), (), out)
            else:
                self.f.seek(dlen, 1)
                if self.f.tell() > size:
                    raise Truncated("the file ends inside a record")
            out.offset = self.f.tell()

    @staticmethod
    def _unpack(data: bytes, fields: dict[str, bytes]) -> bytes:
        compression = fields.get("compression", b"none").decode()
        raw = _decompress(data, compression)
        if "size" in fields and len(raw) != _u32(fields["size"]):
            raise Truncated("a chunk's size does not match its header")
        return raw

    def _record(self, fields: dict[str, bytes], data: bytes, where: tuple, out: _Scan) -> None:
        op = fields.get("op", b"\0")[0]
        if op == 0x07:
            conn = _u32(fields["conn"])
            if conn not in out.conn_by_file.get(id(self), {}):
                info = _ros1_fields(data)
                out.add_connection(
                    self,
                    conn,
                    fields["topic"].decode(),
                    info["type"].decode(),
                    info.get("message_definition", b"").decode(),
                    "msg",
                )
        elif op == 0x02:
            sec, nsec = struct.unpack("<II", fields["time"])
            out.add_message(self, _u32(fields["conn"]), sec * 1_000_000_000 + nsec, where)

    def raw(self, where: tuple) -> bytes:
        data_at, dlen, compression, start, n = where
        if compression == b"none":
            self.f.seek(data_at + start)
            return self.f.read(n)
        if self._chunk is None or self._chunk[0] != data_at:  # chunks hold many messages: keep the last one
            self.f.seek(data_at)
            self._chunk = (data_at, _decompress(self.f.read(dlen), compression.decode()))
        return self._chunk[1][start : start + n]


# -- MCAP -------------------------------------------------------------------------------------------------


def _string(b: bytes, at: int) -> tuple[str, int]:
    n = _u32(b, at)
    return b[at + 4 : at + 4 + n].decode(), at + 4 + n


def _mcap_records(body: bytes) -> bytes:
    """A compressed MCAP chunk's records, decompressed and checked (size, CRC) by rosbags' MCAP decompression."""
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.storage_mcap import decompress

    comp, at = _string(body, 28)
    try:
        return decompress(body[at + 8 : at + 8 + _u64(body, at)], comp, _u64(body, 16), _u32(body, 24))
    except ReaderError as exc:
        raise Truncated(str(exc)) from exc


class _McapFile:
    """An MCAP file scanned record by record: schemas, channels and messages, in chunks or not."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.f = path.open("rb")
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self._chunk: tuple[int, bytes] | None = None

    def scan(self, out: _Scan) -> None:
        if self.f.read(8) != MCAP_MAGIC:
            raise Truncated("not an MCAP file (no MCAP magic)")
        size = self.path.stat().st_size
        while True:
            pos = self.f.tell()
            op = self.f.read(1)
            if not op or op == MCAP_MAGIC[:1]:  # the end, or the closing magic after the footer
                return
            out.offset = pos
            n = _u64(_read(self.f, 8))
            body_at = self.f.tell()
            if op[0] == 0x06:  # chunk: its records, decompressed (an uncompressed one cut off: up to the cut)
                body = self.f.read(n)
                comp, at = _string(body, 28)
                records = body[at + 8 : at + 8 + _u64(body, at)]
                if comp == "":
                    self._records(records, (), out, file_at=body_at + at + 8)
                elif len(body) < n:
                    raise Truncated("the file ends inside a compressed chunk")
                else:
                    self._records(_mcap_records(body), (body_at, n), out)
                if len(body) < n:
                    raise Truncated("the file ends inside a chunk")
            elif op[0] in (0x03, 0x04, 0x05):
                self._records(op + struct.pack("<Q", n) + _read(self.f, n), (), out, file_at=pos)
            elif op[0] in (0x02, 0x0F):  # data end or footer: the messages are all read
                return
            else:
                self.f.seek(n, 1)
                if self.f.tell() > size:
                    raise Truncated("the file ends inside a record")
            out.offset = self.f.tell()

    def _records(self, buf: bytes, chunk: tuple, out: _Scan, file_at: int = 0) -> None:
        at = 0
        while at < len(buf):
            op, n = buf[at], _u64(buf, at + 1)
            body = buf[at + 9 : at + 9 + n]
            if len(body) != n:
                raise Truncated("the file ends inside a chunk's record")
            if op == 0x03:
                sid = struct.unpack_from("<H", body)[0]
                name, p = _string(body, 2)
                enc, p = _string(body, p)
                self.schemas[sid] = (name, enc, body[p + 4 : p + 4 + _u32(body, p)].decode())
            elif op == 0x04:
                cid, sid = struct.unpack_from("<HH", body)
                topic, _ = _string(body, 4)
                name, enc, text = self.schemas.get(sid, ("", "", ""))
                if cid not in out.conn_by_file.get(id(self), {}):
                    out.add_connection(self, cid, topic, name, text, "idl" if enc == "ros2idl" else "msg")
            elif op == 0x05:
                cid, _, log_ns = struct.unpack_from("<HIQ", body)
                where = (*chunk, at + 9 + 22, n - 22) if chunk else (file_at + at + 9 + 22, n - 22)
                out.add_message(self, cid, log_ns, where)
            at += 9 + n

    def raw(self, where: tuple) -> bytes:
        if len(where) == 2:
            self.f.seek(where[0])
            return self.f.read(where[1])
        body_at, n, start, size = where
        if self._chunk is None or self._chunk[0] != body_at:
            self.f.seek(body_at)
            self._chunk = (body_at, _mcap_records(self.f.read(n)))
        return self._chunk[1][start : start + size]


# -- SQLite 3 ---------------------------------------------------------------------------------------------


class _SqliteFile:
    """A rosbag2 SQLite file read row by row (in the table's order) until SQLite reports damage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.db = sqlite3.connect(f"file:{path}?immutable=1", uri=True, check_same_thread=False)

    def scan(self, out: _Scan) -> None:
        try:
            self.db.execute("PRAGMA writable_schema = ON")  # SQLite reads a file shorter than its header says
            topics = self.db.execute("SELECT id, name, type FROM topics").fetchall()
            defs = {}
            try:
                defs = {
                    t: (text, enc)
                    for t, enc, text in self.db.execute(
                        "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
                    )
                }
            except sqlite3.DatabaseError:
                pass  # older bags carry no definitions: the standard store has the usual types
        except sqlite3.DatabaseError as exc:
            raise Truncated(f"SQLite cannot read its topics ({exc})") from exc
        for tid, name, msgtype in topics:
            text, enc = defs.get(msgtype, ("", ""))
            out.add_connection(self, tid, name, msgtype, text, "idl" if enc == "ros2idl" else "msg")
        try:
            for mid, tid, log_ns in self.db.execute("SELECT id, topic_id, timestamp FROM messages"):
                out.offset = mid
                out.add_message(self, tid, log_ns, (mid,))
        except sqlite3.DatabaseError as exc:
            raise Truncated(f"SQLite stops after message row {out.offset} ({exc})") from exc

    def raw(self, where: tuple) -> bytes:
        row = self.db.execute("SELECT data FROM messages WHERE id = ?", where).fetchone()
        return bytes(row[0])


# -- the reader -------------------------------------------------------------------------------------------


class _Scan:
    """What the scans found, across the bag's storage files."""

    def __init__(self) -> None:
        self.connections: list[Connection] = []
        self.conn_by_file: dict[int, dict[int, int]] = {}  # file, its own id -> index in connections
        self.defs: list[tuple[str, str, str]] = []  # (msgtype, definition, format)
        self.entries: list[_Entry] = []
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
        self.entries.append(_Entry(log_ns, conn, (len(self.files) - 1, *where)))


def _kind(p: Path) -> type | None:
    """The scanner of a storage file, by its name (a ROS 1 recorder that did not close leaves `.bag.active`)."""
    if p.suffix == ".bag" or p.name.endswith(".bag.active"):
        return _Ros1File
    return {".mcap": _McapFile, ".db3": _SqliteFile}.get(p.suffix)


def storage_files(path: Path) -> list[Path]:
    """The storage files of a bag: a ROS 1 `.bag`, an `.mcap` / `.db3` file, or those of a ROS 2 bag folder
    (in the order of their split numbers)."""
    if path.is_file():
        return [path] if _kind(path) else []

    def split_number(p: Path) -> tuple[int, str]:
        tail = p.stem.rsplit("_", 1)[-1]
        return (int(tail) if tail.isdigit() else -1, p.name)

    return sorted((p for p in path.iterdir() if p.suffix in (".mcap", ".db3")), key=split_number)


class SalvagedBag:
    """The readable messages of a damaged bag, with `AnyReader`'s interface as `RosbagSequence` uses it."""

    def __init__(self, path: Path) -> None:
        files = storage_files(path)
        if not files:
            raise ValueError("no .bag, .mcap or .db3 file to read")
        scan = _Scan()
        damage: list[tuple[str, int, str]] = []  # (file, its last message's log time, what stopped the scan)
        for p in files:
            scan.offset = 0
            first = len(scan.entries)
            file = _kind(p)(p)
            scan.files.append(file)
            try:
                file.scan(scan)
            except (Truncated, struct.error, ValueError, OSError, KeyError, IndexError, UnicodeDecodeError) as exc:
                where = (
                    f", in the record from byte {scan.offset:,} of {p.stat().st_size:,}"
                    if p.suffix != ".db3" and scan.offset
                    else ""
                )
                last = max((e.log_ns for e in scan.entries[first:]), default=-1)
                damage.append((p.name, last, f"{exc}{where}"))
        self.is2 = not any(_kind(p) is _Ros1File for p in files)
        self.connections = scan.connections
        self._scan = scan
        scan.entries.sort(key=lambda e: e.log_ns)
        self._times = [e.log_ns for e in scan.entries]
        self.start_time = self._times[0] if self._times else 0
        self.end_time = self._times[-1] + 1 if self._times else 0

        def where(last: int) -> str:
            return "at its start" if last < 0 else f"{(last - self.start_time) * 1e-9:.2f} s into the recording"

        self.damaged = "; ".join(f"{name} stops {where(last)} ({why})" for name, last, why in damage)
        self.typestore = self._typestore(scan.defs)

    def _typestore(self, defs: list[tuple[str, str, str]]) -> Any:
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

        typs = dict(get_typestore(Stores.ROS2_HUMBLE if self.is2 else Stores.ROS1_NOETIC).fielddefs)
        for msgtype, text, fmt in defs:
            try:
                typs.update(get_types_from_idl(text) if fmt == "idl" else get_types_from_msg(text, msgtype))
            except Exception:  # a definition rosbags cannot parse: the standard one stands
                continue
        store = get_typestore(Stores.EMPTY)
        store.register(typs)
        return store

    def messages(
        self, connections: list[Connection] | None = None, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[Connection, int, bytes]]:
        """(connection, log time ns, raw bytes) in log-time order, from `start` (ns) to before `stop`."""
        want = None if connections is None else {c.id for c in connections}
        lo = 0 if start is None else bisect.bisect_left(self._times, start)
        hi = len(self._times) if stop is None else bisect.bisect_left(self._times, stop)
        for e in self._scan.entries[lo:hi]:
            if want is None or e.conn in want:
                file = self._scan.files[e.where[0]]
                try:
                    raw = file.raw(e.where[1:])
                except (sqlite3.DatabaseError, OSError, ValueError) as exc:
                    raise Truncated(
                        f"{file.path.name}: the message logged {(e.log_ns - self.start_time) * 1e-9:.2f} s "
                        f"into the bag cannot be read ({exc})"
                    ) from exc
                yield self.connections[e.conn], e.log_ns, raw

    def close(self) -> None:
        for file in self._scan.files:
            (file.db if isinstance(file, _SqliteFile) else file.f).close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # half-built or already closed
            pass

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        if self.is2:
            return self.typestore.deserialize_cdr(raw, msgtype)
        return self.typestore.deserialize_ros1(raw, msgtype)
