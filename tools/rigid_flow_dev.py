"""Development check of the rigid-flow test with ground-truth depth and poses (so only the flow and the
test itself are judged), on a validation sequence: how far the measured flow departs from the rigid flow
on static and on moving pixels, and precision / recall of the test, for a plain and a rigid-initialised
DIS flow, with and without the forward-backward check and the opening.

    .venv/bin/python tools/rigid_flow_dev.py SEQ [--focal 130]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from leovr.config import SelfSupConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T
from selfsup.flow_mask import flow_inside
from selfsup.motion_mask import dis_flow, rigid_flow
from selfsup.supervision import train_frames


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence")
    ap.add_argument("--focal", type=float, default=130.0)
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    frames = train_frames(seq, SelfSupConfig(train_focal_px=a.focal))
    for initialised in (False, True):
        data = []
        for k in range(len(frames) - 1):
            f, g = frames[k], frames[k + 1]
            size = (f.sparse.shape[1], f.sparse.shape[0])
            depth = [cv2.resize(seq[i].depth, size, interpolation=cv2.INTER_NEAREST) for i in (k, k + 1)]
            moving = cv2.resize(seq[k].moving_mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
            T = invert_T(seq[k + 1].T_world_cam) @ seq[k].T_world_cam
            full, rot, valid = rigid_flow(depth[0], T, f.K)
            fb_full, fb_rot, fb_valid = rigid_flow(depth[1], invert_T(T), f.K)
            flow = dis_flow(f.image, g.image, np.where(valid[..., None], full, rot) if initialised else None)
            back = dis_flow(g.image, f.image, np.where(fb_valid[..., None], fb_full, fb_rot) if initialised else None)
            h, w = flow.shape[:2]
            v, u = np.mgrid[0:h, 0:w].astype(np.float32)
            back_at = cv2.remap(back, u + flow[..., 0], v + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            data.append((np.linalg.norm(flow - full, axis=-1), np.linalg.norm(full - rot, axis=-1),
                         np.linalg.norm(flow + back_at, axis=-1), flow_inside(flow) & valid, moving))
        static = np.concatenate([g[r & ~m] for g, _, _, r, m in data])
        print(f"{'rigid-initialised' if initialised else 'plain'} DIS: |flow - rigid| px on static pixels, "
              f"50/75/90th percentile {np.percentile(static, [50, 75, 90]).round(2).tolist()}")
        for fb_px, open_px in ((None, 0), (2.0, 0), (2.0, 3)):
            tp = dropped = mv = 0
            for gap, trans, fb, region, moving in data:
                flag = gap > 0.5 + 0.3 * trans
                if fb_px is not None:
                    flag &= fb < fb_px
                if open_px:
                    flag = cv2.morphologyEx(flag.astype(np.uint8), cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8)) > 0
                flag &= region
                tp += int(np.sum(flag & moving))
                dropped += int(flag.sum())
                mv += int(np.sum(moving & region))
            print(f"  abs 0.5 px, rel 0.3, fb {fb_px}, open {open_px}: recall {tp / max(mv, 1):.3f} "
                  f"precision {tp / max(dropped, 1):.3f}")


if __name__ == "__main__":
    main()
