"""What `leovr info` reports about a sequence: its summary, a ROS bag's topics and pairing, and the
reading speed when asked."""

from __future__ import annotations

import time

from tqdm import tqdm

from leovr.data.sequence import Sequence


def sequence_summary(seq: Sequence, read_frames: bool = False) -> dict:
    """The sequence's `info()`, a bag's topics (`topics`: type, messages, use) and image-scan pairing, and
    with `read_frames` the time to read every frame (`read_frames_per_s`)."""
    out = seq.info().as_dict()
    if hasattr(seq, "topic_table"):
        out |= seq.pairing()
        out["topics"] = seq.topic_table()
    if read_frames:
        t0 = time.perf_counter()
        for _ in tqdm(seq, total=len(seq), desc="reading", unit="frame"):
            pass
        out["read_frames_per_s"] = round(len(seq) / max(time.perf_counter() - t0, 1e-9), 1)
    return out
