"""A ROS 1 bag scanned record by record from its start (the bag header, then chunks with the connections
and messages inside; index records skipped) up to the first damage, and a scanned message's bytes read
again from its place in the file."""

from __future__ import annotations

import bz2
import struct
from pathlib import Path
from typing import Iterator

from leovr.data.bag_scan import Scan, Truncated, read_exact, u32

ROS1_MAGIC = b"#ROSBAG V2.0\n"


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


def _ros1_fields(header: bytes) -> dict[str, bytes]:
    fields, at = {}, 0
    while at < len(header):
        n = u32(header, at)
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
        hlen = u32(buf, at)
        fields = _ros1_fields(buf[at + 4 : at + 4 + hlen])
        dlen = u32(buf, at + 4 + hlen)
        start = at + 8 + hlen
        if start + dlen > len(buf):
            raise Truncated("the file ends inside a chunk's record")
        yield fields, start, dlen
        at = start + dlen


class Ros1File:
    """A ROS 1 bag scanned record by record: bag header, chunks (connections and messages inside),
    index records skipped."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.f = path.open("rb")
        self._chunk: tuple[int, bytes] | None = None

    def scan(self, out: Scan) -> None:
        if self.f.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
            raise Truncated("not a ROS 1 bag (no '#ROSBAG V2.0' line)")
        size = self.path.stat().st_size
        while True:
            pos = self.f.tell()
            head = self.f.read(4)
            if not head:
                return
            out.offset = pos
            hlen = u32(head) if len(head) == 4 else 0
            if len(head) < 4 or hlen > 1 << 20:
                raise Truncated("a record header is cut off or malformed")
            fields = _ros1_fields(read_exact(self.f, hlen))
            dlen = u32(read_exact(self.f, 4))
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
                self._record(fields, read_exact(self.f, dlen), (), out)
            else:
                self.f.seek(dlen, 1)
                if self.f.tell() > size:
                    raise Truncated("the file ends inside a record")
            out.offset = self.f.tell()

    @staticmethod
    def _unpack(data: bytes, fields: dict[str, bytes]) -> bytes:
        compression = fields.get("compression", b"none").decode()
        raw = _decompress(data, compression)
        if "size" in fields and len(raw) != u32(fields["size"]):
            raise Truncated("a chunk's size does not match its header")
        return raw

    def _record(self, fields: dict[str, bytes], data: bytes, where: tuple, out: Scan) -> None:
        op = fields.get("op", b"\0")[0]
        if op == 0x07:
            conn = u32(fields["conn"])
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
            out.add_message(self, u32(fields["conn"]), sec * 1_000_000_000 + nsec, where)

    def raw(self, where: tuple) -> bytes:
        data_at, dlen, compression, start, n = where
        if compression == b"none":
            self.f.seek(data_at + start)
            return self.f.read(n)
        if self._chunk is None or self._chunk[0] != data_at:  # chunks hold many messages: keep the last one
            self.f.seek(data_at)
            self._chunk = (data_at, _decompress(self.f.read(dlen), compression.decode()))
        return self._chunk[1][start : start + n]
