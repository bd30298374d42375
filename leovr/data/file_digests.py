"""Content digests of a recording's files, so that a resumed run notices an input edited in place.

Each file's SHA-1 is computed once and cached by its path, size and modification time (in this process and in
`$LEOVR_CACHE/file_sha1.json`, default `~/.cache/leovr`): resuming over a recording of many GB re-reads only
the files that changed since.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from leovr.data.io import write_text

_memo: dict[str, tuple[int, int, str]] = {}  # absolute path -> (size, mtime_ns, sha1)
_loaded = False
_dirty = False  # digests computed since the cache file was last written


def cache_file() -> Path:
    return Path(os.environ.get("LEOVR_CACHE", Path.home() / ".cache" / "leovr")) / "file_sha1.json"


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    try:
        stored = json.loads(cache_file().read_text())
        _memo.update({k: (int(v[0]), int(v[1]), str(v[2])) for k, v in stored.items()} | _memo)
    except (OSError, ValueError, TypeError, IndexError, AttributeError):
        pass  # no cache yet, or an unreadable one: digests are computed again


def _save() -> None:
    global _dirty
    if not _dirty:
        return
    _dirty = False
    for gone in [k for k in _memo if not os.path.exists(k)]:  # files deleted since: forgotten
        del _memo[gone]
    try:
        cache_file().parent.mkdir(parents=True, exist_ok=True)
        write_text(cache_file(), json.dumps({k: list(v) for k, v in _memo.items()}))
    except OSError:
        pass  # a read-only home: the digests stay in this process


def file_sha1(path: Path) -> str:
    """SHA-1 of the file's contents (cached by path, size and modification time)."""
    global _dirty
    _load()
    st = path.stat()
    key = str(path.resolve())
    hit = _memo.get(key)
    if hit is not None and hit[:2] == (st.st_size, st.st_mtime_ns):
        return hit[2]
    with open(path, "rb") as fh:
        digest = hashlib.file_digest(fh, "sha1").hexdigest()
    _memo[key] = (st.st_size, st.st_mtime_ns, digest)
    _dirty = True
    return digest


def file_digests(path: Path) -> dict[str, str]:
    """Every file under `path` (or the file itself), by path relative to it, with its content SHA-1."""
    path = Path(path)
    if path.is_file():
        out = {path.name: file_sha1(path)}
    else:
        out = {}
        for root, dirs, files in os.walk(path):
            dirs.sort()
            for name in sorted(files):
                p = Path(root) / name
                try:
                    out[str(p.relative_to(path))] = file_sha1(p)
                except OSError:
                    continue  # vanished or unreadable: the reader reports it when it needs the file
    _save()
    return out


def digest_of(digests: dict[str, str]) -> str:
    """One SHA-1 over a folder's file digests."""
    h = hashlib.sha1()
    for rel in sorted(digests):
        h.update(f"{rel}:{digests[rel]}\n".encode())
    return h.hexdigest()


def changed_files(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """The files that differ between two listings: edited, added or removed."""
    edited = [f"{rel} (changed)" for rel in sorted(old.keys() & new.keys()) if old[rel] != new[rel]]
    return (
        edited
        + [f"{rel} (new)" for rel in sorted(new.keys() - old.keys())]
        + [f"{rel} (removed)" for rel in sorted(old.keys() - new.keys())]
    )
