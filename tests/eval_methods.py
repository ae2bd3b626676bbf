"""Test-only methods for the evaluation harness: `SPECS`, passed to the pipeline or put in place of the registry.

`oracle` cheats on purpose: its "training" records the dataset folder, and at run time it reads
each scene's ground truth from disk (the harness hides it from the record it passes).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.sim.workspace import DEFAULT_TABLE


def _rng(key) -> np.random.Generator:
    import jax

    return np.random.default_rng(np.asarray(jax.random.key_data(key)))


def train_oracle(context: TrainContext) -> Path:
    context.out_dir.mkdir(parents=True, exist_ok=True)
    (context.out_dir / "dataset.json").write_text(
        json.dumps({"dataset": str(context.dataset_dir), "fraction": context.fraction})
    )
    return context.out_dir


@dataclasses.dataclass
class OracleMethod:
    dataset_dir: Path
    name: str = "oracle"

    def describe(self) -> dict:
        return {"dataset": str(self.dataset_dir)}

    def run(self, scenes, key):
        from ocplace.sim.dataset.records import SceneInfo, read_meta
        from ocplace.sim.metric import feasible_grid, sample_oracle_placements

        rng = _rng(key)
        outputs = []
        for scene in scenes:
            truth = SceneInfo(read_meta(self.dataset_dir / scene.split / scene.id))
            samples = sample_oracle_placements(feasible_grid(truth.problem()), 8, rng)
            outputs.append(
                MethodOutput(
                    mode=truth.oracle.placement,
                    samples=samples,
                    parsed=tuple((t.reference_name, t.relation) for t in truth.tuples),
                    grounded=tuple(t.token_index for t in truth.tuples),
                )
            )
        return outputs


def load_oracle(context: LoadContext) -> OracleMethod:
    return OracleMethod(Path(json.loads((context.run_dir / "dataset.json").read_text())["dataset"]))


@dataclasses.dataclass
class CentreMethod:
    """Places at the centre of the table, whatever it is told."""

    name: str = "centre"

    def describe(self) -> dict:
        return {"placement": [0.0, 0.0]}

    def run(self, scenes, key):
        return [MethodOutput(mode=np.zeros(2), samples=None) for _ in scenes]


@dataclasses.dataclass
class FailingMethod:
    name: str = "failing"

    def describe(self) -> dict:
        return {}

    def run(self, scenes, key):
        return [MethodOutput(mode=None, samples=None, failure="no reference found (test method)") for _ in scenes]


@dataclasses.dataclass
class FlakyMethod:
    """Raises on scenes with an odd index, places at the centre otherwise."""

    name: str = "flaky"

    def describe(self) -> dict:
        return {}

    def run(self, scenes, key):
        odd = [s.id for s in scenes if s.index % 2]
        if odd:
            raise RuntimeError(f"cannot handle {odd[0]}")
        return [MethodOutput(mode=np.zeros(2), samples=None) for _ in scenes]


@dataclasses.dataclass
class RandomMethod:
    """Uniform samples over the table from the key; the mode is the first sample; as its confidence, the share of
    samples right of the centre."""

    num_samples: int = 8
    name: str = "random"

    def describe(self) -> dict:
        return {"num_samples": self.num_samples}

    def run(self, scenes, key):
        rng = _rng(key)
        low, high = DEFAULT_TABLE.bounds
        outputs = []
        for _ in scenes:
            samples = rng.uniform(low, high, size=(self.num_samples, 2))
            outputs.append(MethodOutput(mode=samples[0], samples=samples, confidence=float(np.mean(samples[:, 0] > 0))))
        return outputs


# Module-level loaders, not lambdas: the pipeline sends specs to worker processes, which pickle them by name.
def load_centre(context: LoadContext) -> CentreMethod:
    return CentreMethod()


def load_failing(context: LoadContext) -> FailingMethod:
    return FailingMethod()


def load_flaky(context: LoadContext) -> FlakyMethod:
    return FlakyMethod()


def load_random(context: LoadContext) -> RandomMethod:
    return RandomMethod(min(context.num_samples, 64))


SPECS = {
    spec.name: spec
    for spec in (
        MethodSpec("oracle", "Oracle", load=load_oracle, train=train_oracle),
        MethodSpec("centre", "Table centre", load=load_centre),
        MethodSpec("failing", "Always fails", load=load_failing),
        MethodSpec("flaky", "Raises on odd scenes", load=load_flaky),
        MethodSpec("random", "Uniform random", load=load_random),
    )
}
