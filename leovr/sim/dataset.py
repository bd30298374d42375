"""Train / val / test splits of simulated sequences from disjoint seeds (regenerated, never committed).

A split's sequences are written under `root/<split>/<scenario>_<lidar>_<light>_s<seed>/`; finished
sequences (with sequence.yaml) are skipped, so an interrupted run resumes. `manifest.json` lists them.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from tqdm import tqdm

from leovr.config import SimulateConfig
from leovr.data.io import write_text
from leovr.sim.simulate import simulate

SEED_BASE = {"train": 1000, "val": 2000, "test": 3000}  # disjoint seed ranges per split
SCENARIO_CYCLE = ("city_loop", "straight", "dynamic")


@dataclass
class Recipe:
    name: str = "default"
    sequences: dict[str, int] = field(default_factory=lambda: {"train": 9, "val": 3, "test": 3})
    lidars: tuple[str, ...] = ("mid40", "vlp16")
    lights: tuple[str, ...] = ("day", "night")
    frames: int = 40
    scenarios: tuple[str, ...] = SCENARIO_CYCLE  # sequence i of a split takes scenarios[i % len]
    camera: tuple[int, int, float] = (448, 256, 260.0)  # width, height, focal length (px)

    def items(self) -> list[tuple[str, SimulateConfig]]:
        out = []
        for split, n in self.sequences.items():
            for i in range(n):
                for lidar in self.lidars:
                    for light in self.lights:
                        width, height, focal = self.camera
                        cfg = SimulateConfig(
                            scenario=self.scenarios[i % len(self.scenarios)],
                            lidar=lidar,
                            light=light,
                            seed=SEED_BASE[split] + i,
                            frames=self.frames,
                            width=width,
                            height=height,
                            focal=focal,
                        )
                        out.append((split, cfg))
        return out


RECIPES = {
    "default": Recipe(),
    "tiny": Recipe("tiny", {"train": 3, "val": 1, "test": 1}, ("mid40", "vlp16"), ("day",), 8),
    # movers that break photometric self-supervision, with their moving masks (`leovr bench selfsup`)
    "traffic": Recipe("traffic", {"train": 3, "val": 1, "test": 2}, ("mid40",), ("day",), 40, ("traffic",)),
}


def default_root() -> Path:
    return Path(os.environ.get("LEOVR_CACHE", Path.home() / ".cache" / "leovr")) / "datasets"


def make_dataset(recipe: Recipe, root: Path | None = None, progress: bool = True) -> Path:
    """Render every sequence of the recipe that is not already complete; return the dataset folder."""
    base = (root or default_root()) / recipe.name
    entries = []
    items = recipe.items()
    for split, cfg in tqdm(items, desc=f"dataset {recipe.name}", unit="seq", disable=not progress):
        rel = Path(split) / f"{cfg.scenario}_{cfg.lidar}_{cfg.light}_s{cfg.seed}"
        if not (base / rel / "sequence.yaml").is_file():
            simulate(cfg, base / rel, progress=False)
        entries.append({"split": split, "path": str(rel), **cfg.model_dump()})
    manifest = {"recipe": asdict(recipe), "sequences": entries}
    write_text(base / "manifest.json", json.dumps(manifest, indent=2) + "\n")
    return base
