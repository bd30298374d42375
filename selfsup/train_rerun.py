"""A Rerun recording of self-supervised training: a few frames' flow mask, warped neighbour, photometric
error and depth, once per epoch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from leovr.config import SelfSupConfig
from leovr.depth.inference import forward_padded
from selfsup.dataset import SelfSupSamples
from selfsup.losses import photometric_error
from selfsup.objective import batch_terms

RERUN_FRAMES = 2  # frames logged to --rerun each epoch


class RerunView:
    """Flow mask, warped neighbour, photometric error and depth of a few frames, once per epoch."""

    def __init__(self, path: Path, cfg: SelfSupConfig, dataset: SelfSupSamples) -> None:
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream("leovr_selfsup")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(str(path))
        n = len(dataset)
        self.picks = sorted({int(round(x)) for x in np.linspace(0, n - 1, min(RERUN_FRAMES, n))})

    @torch.no_grad()
    def log(
        self, epoch: int, model: torch.nn.Module, dataset: SelfSupSamples, cfg: SelfSupConfig, refine: bool
    ) -> None:
        rr = self.rr
        self.rec.set_time("epoch", sequence=epoch)
        model.eval()
        for j in self.picks:
            b = {k: v[None] for k, v in dataset[j].items()}
            depth, _ = forward_padded(model, b["image"], b["sparse"])
            _, _, extra = batch_terms(depth, b, cfg, refine)
            pe = photometric_error(b["image"], extra["warped_prev"])[0, 0]
            k, i = (int(x) for x in b["key"][0])
            base = f"train/seq{k}/frame{i:06d}"
            to_u8 = lambda t: (t.clamp(0, 1) * 255).byte().permute(1, 2, 0).numpy()  # noqa: E731
            self.rec.log(f"{base}/image", rr.Image(to_u8(b["image"][0])))
            self.rec.log(f"{base}/warped_prev", rr.Image(to_u8(extra["warped_prev"][0])))
            self.rec.log(f"{base}/flow_mask_prev", rr.Image(extra["mask_prev"][0, 0].byte().numpy() * 255))
            self.rec.log(f"{base}/photometric_error", rr.Image((pe.clamp(0, 0.5) * 510).byte().numpy()))
            self.rec.log(f"{base}/depth", rr.DepthImage(depth[0, 0].float().numpy(), meter=1.0, colormap="turbo"))
        model.train()
