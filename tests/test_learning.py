"""Training learns, not only runs: a tiny supervised run and a tiny self-supervised run (fixed seed, about
a minute each on 224 x 128 frames) bring the held-out MAE clearly below the untrained network's and below
a network-free guess (the training frames' median depth everywhere), on a small rendered set: two
training sequences, one held-out sequence of another seed."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from leovr.bench.selfsup_models import score
from leovr.config import SelfSupConfig, TrainConfig
from leovr.data import open_sequence
from leovr.depth.dataset import split_sequences
from leovr.depth.inference import load_generator
from leovr.depth.network import DepthGenerator
from leovr.depth.train import train_supervised
from leovr.depth.train_state import generator_config
from leovr.pipeline.refine import run_refine
from leovr.sim.dataset import Recipe, make_dataset
from selfsup.trainer import train_selfsup

SMALL = dict(channels=[8, 16, 16, 32, 32], blocks=[1, 1, 1, 1], seed=0)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    recipe = Recipe("learn", {"train": 2, "val": 1, "test": 1}, ("mid40",), ("day",), 8, camera=(224, 128, 130.0))
    root = make_dataset(recipe, tmp_path_factory.mktemp("learn"), progress=False)
    return root, [open_sequence(p) for p in split_sequences(root, "test")]


def median_guess_mae(root, tests) -> float:
    """MAE of the training frames' median depth predicted everywhere (no network)."""
    train = [open_sequence(p) for p in split_sequences(root, "train")]
    med = float(np.median(np.concatenate([s[i].depth[s[i].depth > 0] for s in train for i in range(len(s))])))
    errs = [np.abs(s[i].depth[s[i].depth > 0] - med) for s in tests for i in range(len(s))]
    return float(np.concatenate(errs).mean())


def mae(model, tests) -> float:
    """Held-out MAE against dense ground truth (the network at the frames' own resolution)."""
    return score(model, tests, "full", None, [0.0, 1000.0])["mae_m"]


@pytest.mark.slow
def test_supervised_training_learns(rendered, tmp_path):
    root, tests = rendered
    cfg = TrainConfig(dataset=str(root), epochs=15, sigma_epochs=0, batch_size=4, lr=3e-3, output="absolute", **SMALL)
    torch.manual_seed(0)
    untrained = mae(DepthGenerator(generator_config(cfg)), tests)
    train_supervised(cfg, tmp_path / "run", progress=False)
    trained = mae(load_generator(tmp_path / "run" / "best.pt"), tests)
    assert trained < 0.5 * untrained, (trained, untrained)
    assert trained < median_guess_mae(root, tests), trained


@pytest.mark.slow
def test_selfsup_training_learns(rendered, tmp_path):
    root, tests = rendered
    # 120 steps: the landmarks' depth (L_f) weighs more than in a full run, so that so few steps show learning
    cfg = SelfSupConfig(
        epochs=20,
        init_fraction=1.0,
        batch_size=2,
        lr=3e-3,
        weight_feature=1.0,
        train_focal_px=None,
        loop_closure=False,
        **SMALL,
    )
    torch.manual_seed(0)
    start = DepthGenerator(generator_config(cfg))  # the trainer's initial weights (same seed)
    untrained = mae(start, tests)
    train_selfsup(cfg, split_sequences(root, "train"), tmp_path / "run", run_refine, progress=False)
    # the uncertainty head is trained too (Gaussian NLL at the LiDAR-backed landmarks), and its loss falls
    nll = [json.loads(x)["nll"] for x in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert nll[-1] < 0.5 * nll[0], nll
    head = torch.load(tmp_path / "run" / "generator.pt", weights_only=False)["model"]
    assert any(not torch.equal(head[k], v) for k, v in start.state_dict().items() if k.startswith("sigma_head"))
    trained = mae(load_generator(tmp_path / "run" / "generator.pt"), tests)
    # the untrained network returns its classical prior: training must improve on the prior itself
    assert trained < 0.9 * untrained, (trained, untrained)
    assert trained < median_guess_mae(root, tests), trained
