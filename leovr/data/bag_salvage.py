"""The messages of a bag that cannot be opened whole: a recorder killed mid-write leaves a ROS 1 bag
without its index, an MCAP file without its summary (and a ROS 2 bag without metadata.yaml), a SQLite
file cut off inside its pages. Each storage file is scanned from its start, record by record, up to the
first damage (`bag_scan_ros1`, `bag_scan_mcap`, `bag_scan_sqlite`); the messages before it are read as from
an intact bag (the subset of `rosbags`' `AnyReader` that `RosbagSequence` uses), and `damaged` says where
the scan stopped.

The scan keeps each message's place in the file, not its data: memory stays flat in the bag's length.
Message types come from the definitions the bag carries, else from the standard ROS type store.
"""

from __future__ import annotations

import bisect
import sqlite3
import struct
from pathlib import Path
from typing import Any, Iterator

from leovr.data.bag_scan import Connection, Scan, Truncated
from leovr.data.bag_scan_mcap import McapFile
from leovr.data.bag_scan_ros1 import Ros1File
from leovr.data.bag_scan_sqlite import SqliteFile


def _kind(p: Path) -> type | None:
    """The scanner of a storage file, by its name (a ROS 1 recorder that did not close leaves `.bag.active`)."""
    if p.suffix == ".bag" or p.name.endswith(".bag.active"):
        return Ros1File
    return {".mcap": McapFile, ".db3": SqliteFile}.get(p.suffix)


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
        scan = Scan()
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
        self.is2 = not any(_kind(p) is Ros1File for p in files)
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
            (file.db if isinstance(file, SqliteFile) else file.f).close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # half-built or already closed
            pass

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        if self.is2:
            return self.typestore.deserialize_cdr(raw, msgtype)
        return self.typestore.deserialize_ros1(raw, msgtype)
