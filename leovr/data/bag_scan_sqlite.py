"""A rosbag2 SQLite file's topics and message rows read in the table's order until SQLite reports damage,
and a scanned message's bytes read again by its row."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from leovr.data.bag_scan import Scan, Truncated


class SqliteFile:
    """A rosbag2 SQLite file read row by row (in the table's order) until SQLite reports damage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.db = sqlite3.connect(f"file:{path}?immutable=1", uri=True, check_same_thread=False)

    def scan(self, out: Scan) -> None:
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
