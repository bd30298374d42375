"""The one pass over a ROS bag's messages of the chosen topics when it is opened: the images' and clouds'
stamps (not their data), each cloud's point-time span, the CameraInfo, the static transforms and the
ground-truth poses; a damaged bag's pass stops at the damage and keeps what came before it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from leovr.data import ros_messages as rm
from leovr.data.bag_topics import BagTopic
from leovr.errors import DataError


@dataclass
class BagIndex:
    """What one pass over the bag's stamps found."""

    images: list[tuple[int, int]] = field(default_factory=list)  # (log time, header stamp), ns
    clouds: list[tuple[int, int]] = field(default_factory=list)
    spans: list[tuple[float, float, bool] | None] = field(default_factory=list)  # each cloud's point times
    poses: list[tuple[int, np.ndarray, str]] = field(default_factory=list)  # (stamp ns, T_world_body, body frame)
    info: Any = None
    tree: rm.FrameTree = field(default_factory=rm.FrameTree)
    camera_frame: str = ""
    lidar_frame: str = ""
    damaged: str = ""  # why the pass stopped early, when it did
    log_span: dict[str, tuple[int, int]] = field(default_factory=dict)  # topic -> first and last log time read


def index_bag(
    reader: Any,
    path: Path,
    topics: dict[str, BagTopic],
    camera: str,
    lidar: str | None,
    info_topic: str | None,
    pose_topic: str | None,
) -> BagIndex:
    """One pass over the bag's messages of the chosen topics: stamps, calibration, static transforms."""
    idx = BagIndex()
    wanted = {camera, lidar, info_topic, pose_topic, "/tf_static", "tf_static"} - {None}
    conns = [c for t in wanted if t in topics for c in topics[t].connections]
    n = 0
    try:
        for conn, log_ns, raw in reader.messages(connections=conns):
            n += 1
            topic = conn.topic
            first = idx.log_span.get(topic, (log_ns, log_ns))[0]
            idx.log_span[topic] = (first, log_ns)
            if topic == info_topic and idx.info is not None:
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if topic == camera:
                idx.images.append((log_ns, rm.stamp_ns(msg)))
                idx.camera_frame = idx.camera_frame or str(msg.header.frame_id)
            elif topic == lidar:
                idx.clouds.append((log_ns, rm.stamp_ns(msg)))
                idx.spans.append(rm.cloud_time_range(msg))
                idx.lidar_frame = idx.lidar_frame or str(msg.header.frame_id)
            elif topic == info_topic:
                idx.info = msg
            elif topic == pose_topic:
                T, body = rm.pose_matrix(msg, conn.msgtype)
                idx.poses.append((rm.stamp_ns(msg), T, body))
            elif conn.msgtype == rm.TF_TYPE:
                idx.tree.add(msg)
    except Exception as exc:  # a truncated or damaged bag: what came before it stays usable
        idx.damaged = f"unreadable after message {n} ({type(exc).__name__}: {exc})"
    if not idx.images:
        raise DataError(path, f"no image could be read from {camera}" + (f": {idx.damaged}" if idx.damaged else ""))
    return idx
