"""Supervised training: runs, checkpoints every epoch, resumes (with the settings it began with), then trains the
uncertainty head; both trainers share the optimiser, network and checkpoint files."""

from __future__ import annotations

import json

import pytest
import torch

from leovr.config import SelfSupConfig, TrainConfig
from leovr.depth.epochs import Epoch, train_epochs
from leovr.depth.train import optimiser, train_supervised
from leovr.depth.train_state import generator_config
from leovr.errors import DataError
from leovr.sim.dataset import Recipe, make_dataset


@pytest.mark.slow
def test_train_checkpoints_resume_and_sigma_phase(tmp_path):
    root = make_dataset(Recipe("t", {"train": 1, "val": 1}, ("mid40",), ("day",), 3), tmp_path / "data", progress=False)
    cfg = TrainConfig(
        dataset=str(root),
        epochs=2,
        sigma_epochs=1,
        batch_size=2,
        lr=1e-3,
        channels=[8, 8, 16, 16, 16],
        blocks=[1, 1, 1, 1],
    )
    out = tmp_path / "run"
    train_supervised(cfg.model_copy(update={"epochs": 1, "sigma_epochs": 0}), out, progress=False)
    first = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert len(first) == 1 and first[0]["phase"] == "depth"
    state = torch.load(out / "checkpoint_last.pt", weights_only=False)
    assert state["epoch"] == 0
    head_before = {k: v.clone() for k, v in state["model"].items() if k.startswith("sigma_head")}
    r = train_supervised(cfg, out, resume=True, progress=False)
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in log] == [1, 2, 3] and [x["phase"] for x in log] == ["depth", "depth", "sigma"]
    assert all(x["val_mae_m"] > 0 and x["train_loss"] == x["train_loss"] for x in log)  # finite
    assert r["epoch"] == 3
    final = torch.load(out / "checkpoint_last.pt", weights_only=False)["model"]
    assert any(not torch.equal(final[k], v) for k, v in head_before.items())  # the sigma head was trained
    assert (out / "best.pt").is_file()
    assert (out / "log.csv").read_text().splitlines()[0].startswith("epoch,phase,")
    # the same files and checks as self-supervised training: another learning rate would silently be another run
    with pytest.raises(DataError, match=r"other settings \(lr\)"):
        train_supervised(cfg.model_copy(update={"epochs": 3, "lr": 5e-4}), out, resume=True, progress=False)


@pytest.mark.slow
def test_fine_tuning_starts_from_init_checkpoint_and_rejects_other_networks(tmp_path):
    root = make_dataset(Recipe("t", {"train": 1, "val": 1}, ("mid40",), ("day",), 2), tmp_path / "data", progress=False)
    small = dict(dataset=str(root), epochs=1, sigma_epochs=0, batch_size=2, lr=1e-3, blocks=[1, 1, 1, 1])
    cfg = TrainConfig(channels=[8, 8, 16, 16, 16], **small)
    train_supervised(cfg, tmp_path / "a", progress=False)
    base = torch.load(tmp_path / "a" / "best.pt", weights_only=False)["model"]
    # lr 0 and the depth phase only: the fine-tuned weights must equal the initial ones (BN statistics aside)
    tuned_cfg = cfg.model_copy(update={"init_checkpoint": str(tmp_path / "a" / "best.pt"), "lr": 1e-12})
    train_supervised(tuned_cfg, tmp_path / "b", progress=False)
    tuned = torch.load(tmp_path / "b" / "best.pt", weights_only=False)["model"]
    weights = [k for k in base if k.endswith("weight") and "bn" not in k and base[k].dim() == 4]
    assert weights and all(torch.allclose(base[k], tuned[k], atol=1e-6) for k in weights)
    # resuming reads the run's own checkpoint: the starting weights need not be named again
    resumed = train_supervised(
        tuned_cfg.model_copy(update={"init_checkpoint": None, "epochs": 2}), tmp_path / "b", resume=True, progress=False
    )
    assert resumed["epoch"] == 2
    other = TrainConfig(channels=[8, 8, 16, 16, 32], init_checkpoint=str(tmp_path / "a" / "best.pt"), **small)
    with pytest.raises(DataError, match="init checkpoint"):
        train_supervised(other, tmp_path / "c", progress=False)


def test_training_prior_takes_the_image_side_of_depth_edges_like_inference(tmp_path):
    """A residual network is trained over the prior it gets at inference: the image picks each depth
    edge's side (`prior_edges: image`), and `prior_edges: nearest` gives the nearest-return prior."""
    import numpy as np

    from leovr.depth.dataset import DepthSamples, split_sequences
    from leovr.depth.prior import interpolated_fill

    root = make_dataset(Recipe("t", {"train": 1}, ("vlp16",), ("day",), 1), tmp_path / "data", progress=False)
    seqs = split_sequences(root, "train")
    with_image = DepthSamples(seqs, random_input=False, with_prior=True)[0]
    nearest = DepthSamples(seqs, random_input=False, with_prior=True, image_edges=False)[0]
    sparse = with_image["sparse"][0].numpy()
    image = (with_image["image"].permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)
    np.testing.assert_allclose(with_image["prior"][0].numpy(), interpolated_fill(sparse, image=image), rtol=1e-6)
    np.testing.assert_allclose(nearest["prior"][0].numpy(), interpolated_fill(sparse), rtol=1e-6)
    assert (with_image["prior"] != nearest["prior"]).sum() > 100  # the simulated street has depth edges


def test_the_epoch_loop_steps_once_per_batch_and_hands_each_epoch_the_means_of_its_terms():
    """The loop both trainers run: a step of the epoch's optimiser per batch, then `end` with the mean of each term
    over the epoch's batches; the last epoch's record comes back. Loss (w - x)^2 / 2 under SGD at 0.25: each step
    moves w a quarter of the way to the batch's x."""
    w = torch.nn.Parameter(torch.tensor([4.0]))
    opt = torch.optim.SGD([w], lr=0.25)
    batches = [{"x": torch.tensor([1.0])}, {"x": torch.tensor([3.0])}]

    def loss(b: dict) -> tuple[torch.Tensor, dict[str, float]]:
        value = 0.5 * ((w - b["x"]) ** 2).sum()
        return value, {"loss": value.item(), "w": w.item()}

    seen = []

    def end(epoch: int, means: dict[str, float], seconds: float) -> dict:
        seen.append((epoch, means))
        return {"epoch": epoch + 1, **means}

    record = train_epochs(range(1, 3), lambda e: Epoch(batches, opt, loss, f"epoch {e}"), end, show=False)
    assert [e for e, _ in seen] == [1, 2]
    assert seen[0][1] == pytest.approx({"loss": (4.5 + 0.03125) / 2, "w": (4.0 + 3.25) / 2})
    assert record == pytest.approx({"epoch": 3, "loss": (2.392578125 + 0.0645751953125) / 2, "w": 2.9140625})
    assert w.item() == pytest.approx(2.73046875)


@pytest.mark.parametrize("model", [TrainConfig, SelfSupConfig])
def test_both_trainers_optimise_and_build_their_network_from_the_same_settings(model):
    """Supervised and self-supervised training read one optimiser model and one network model: the same YAML keys
    set the same Adam schedule and the same generator."""
    cfg = model(lr=1e-3, lr_step_epochs=2, lr_gamma=0.5, channels=[8, 8, 16, 16, 16], blocks=[1, 1, 1, 1])
    weight = torch.nn.Parameter(torch.zeros(3))
    opt, sched = optimiser([weight], cfg)
    rates = []
    for _ in range(5):
        rates.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert rates == pytest.approx([1e-3, 1e-3, 5e-4, 5e-4, 2.5e-4])
    net = generator_config(cfg)
    assert net.channels == (8, 8, 16, 16, 16) and net.blocks == (1, 1, 1, 1) and net.output == "fusion"
