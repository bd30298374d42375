"""An MCAP file scanned record by record from its start (schemas, channels and messages, in chunks or
not) up to the first damage, and a scanned message's bytes read again from its place in the file."""

from __future__ import annotations

import struct
from pathlib import Path

from leovr.data.bag_scan import Scan, Truncated, read_exact, u32, u64

MCAP_MAGIC = b"\x89MCAP0\r\n"


def _string(b: bytes, at: int) -> tuple[str, int]:
    n = u32(b, at)
    return b[at + 4 : at + 4 + n].decode(), at + 4 + n


def _mcap_records(body: bytes) -> bytes:
    """A compressed MCAP chunk's records, decompressed and checked (size, CRC) by rosbags' MCAP decompression."""
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.storage_mcap import decompress

    comp, at = _string(body, 28)
    try:
        return decompress(body[at + 8 : at + 8 + u64(body, at)], comp, u64(body, 16), u32(body, 24))
    except ReaderError as exc:
        raise Truncated(str(exc)) from exc


class McapFile:
    """An MCAP file scanned record by record: schemas, channels and messages, in chunks or not."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.f = path.open("rb")
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self._chunk: tuple[int, bytes] | None = None

    def scan(self, out: Scan) -> None:
        if self.f.read(8) != MCAP_MAGIC:
            raise Truncated("not an MCAP file (no MCAP magic)")
        size = self.path.stat().st_size
        while True:
            pos = self.f.tell()
            op = self.f.read(1)
            if not op or op == MCAP_MAGIC[:1]:  # the end, or the closing magic after the footer
                return
            out.offset = pos
            n = u64(read_exact(self.f, 8))
            body_at = self.f.tell()
            if op[0] == 0x06:  # chunk: its records, decompressed (an uncompressed one cut off: up to the cut)
                body = self.f.read(n)
                comp, at = _string(body, 28)
                records = body[at + 8 : at + 8 + u64(body, at)]
                if comp == "":
                    self._records(records, (), out, file_at=body_at + at + 8)
                elif len(body) < n:
                    raise Truncated("the file ends inside a compressed chunk")
                else:
                    self._records(_mcap_records(body), (body_at, n), out)
                if len(body) < n:
                    raise Truncated("the file ends inside a chunk")
            elif op[0] in (0x03, 0x04, 0x05):
                self._records(op + struct.pack("<Q", n) + read_exact(self.f, n), (), out, file_at=pos)
            elif op[0] in (0x02, 0x0F):  # data end or footer: the messages are all read
                return
            else:
                self.f.seek(n, 1)
                if self.f.tell() > size:
                    raise Truncated("the file ends inside a record")
            out.offset = self.f.tell()

    def _records(self, buf: bytes, chunk: tuple, out: Scan, file_at: int = 0) -> None:
        at = 0
        while at < len(buf):
            op, n = buf[at], u64(buf, at + 1)
            body = buf[at + 9 : at + 9 + n]
            if len(body) != n:
                raise Truncated("the file ends inside a chunk's record")
            if op == 0x03:
                sid = struct.unpack_from("<H", body)[0]
                name, p = _string(body, 2)
                enc, p = _string(body, p)
                self.schemas[sid] = (name, enc, body[p + 4 : p + 4 + u32(body, p)].decode())
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
