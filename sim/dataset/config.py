"""What a dataset holds: splits, levels, sizes. The defaults are the paper's."""

from __future__ import annotations

import dataclasses
import hashlib

from ocplace.errors import DatasetConfigError
from ocplace.vocabulary import (
    COLOUR_VARIANTS,
    DEV_SPLITS,
    LEVELS,
    LIBRARY_SPLITS,
    OBJECT_POOLS,
    TEST_SUBSETS,
    TEXTURE_SPLITS,
)

LEVEL_REFERENCES = {"table": 0, "1obj": 1, "2obj": 2}  # object references per instruction
# The position of a split here seeds its scenes (with the dataset seed and the scene index): new splits go at
# the end, so old ones keep theirs, and no two splits draw from one stream. The dev splits come after every
# test subset, so their scenes are never a test subset's.
SPLIT_NAMES = ("train", *TEST_SUBSETS, *DEV_SPLITS)
# A subset of a user's own catalogue draws from a stream named by its name, apart from every split above.
_OWN_STREAM_BASE = 1_000_000


def split_stream(name: str) -> int:
    """The seed stream of split `name`: its place in SPLIT_NAMES, or, for a subset of a user's catalogue, a number
    from its name's hash beyond them, so no two splits share one."""
    if name in SPLIT_NAMES:
        return SPLIT_NAMES.index(name)
    return _OWN_STREAM_BASE + int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "big")


def generate_advice(out, split: str) -> str:
    """How to get the scenes of `split` into `out`: the `generate` command for a split there is, else the splits."""
    if split in SPLIT_NAMES:
        return f"generate them with `ocplace generate --out {out} --split {split}`"
    return (
        f"{split!r} is no split of the benchmark (they are {', '.join(SPLIT_NAMES)}); a subset of your own catalogue "
        f"is generated with `ocplace generate --out DIR --catalogue FILE --subset {split}` (docs/library.md)"
    )


@dataclasses.dataclass(frozen=True)
class SplitConfig:
    name: str
    levels: tuple[tuple[str, int], ...]  # (level, number of scenes)
    objects: str  # object pool the scene and held objects come from (OBJECT_POOLS: a library split or seen_colour)
    textures: str  # table texture split (TEXTURE_SPLITS)
    instructions: str  # instruction style: "seen" or "unseen"

    @property
    def num_scenes(self) -> int:
        return sum(count for _, count in self.levels)


def _test_levels(total: int) -> tuple[tuple[str, int], ...]:
    """Levels in the paper's 9:9:22 ratio."""
    table = round(total * 9 / 40)
    return (("table", table), ("1obj", table), ("2obj", total - 2 * table))


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    splits: tuple[SplitConfig, ...]
    seed: int = 0
    max_scene_attempts: int = 20  # new scenes drawn for one index before giving up
    max_relation_attempts: int = 20  # relation draws per scene before drawing a new scene
    png_compression: int = 1  # 0-9; 1 writes ~3x faster than the default for ~10% more bytes
    # A test-only dataset of a user's catalogue (`catalogue_library.catalogue_record`): its splits are its subsets.
    catalogue: dict | None = None
    distractors: str | None = None  # the library split whose objects are mixed in as distractors; None: none

    def split(self, name: str) -> SplitConfig:
        for split in self.splits:
            if split.name == name:
                return split
        raise DatasetConfigError(f"unknown split {name!r}; this dataset has {[s.name for s in self.splits]}")

    def own_subsets(self) -> tuple[str, ...]:
        """The subsets of the user's catalogue this dataset may hold (none for the benchmark's)."""
        return tuple((self.catalogue or {}).get("subsets", {}))

    def validate(self) -> None:
        if self.distractors is not None and (self.catalogue is None or self.distractors not in LIBRARY_SPLITS):
            raise DatasetConfigError(f"distractors are a library split ({LIBRARY_SPLITS}) of a catalogue's dataset")
        for split in self.splits:
            own = split.name in self.own_subsets()
            if split.name not in SPLIT_NAMES and not own:
                known = (*SPLIT_NAMES, *self.own_subsets())
                raise DatasetConfigError(f"unknown split {split.name!r}; choose from {known}")
            if own and split.objects != split.name:
                raise DatasetConfigError(f"{split.name}: a catalogue's subset draws from its own objects")
            for level, count in split.levels:
                if level not in LEVELS:
                    raise DatasetConfigError(f"unknown level {level!r} in {split.name}; choose from {LEVELS}")
                if count < 0:
                    raise DatasetConfigError(f"{split.name}/{level}: negative scene count {count}")
            if split.num_scenes == 0:
                raise DatasetConfigError(f"split {split.name!r} has zero scenes")
            if (split.objects not in OBJECT_POOLS and not own) or split.textures not in TEXTURE_SPLITS:
                raise DatasetConfigError(
                    f"{split.name}: object pools are {OBJECT_POOLS}, texture splits {TEXTURE_SPLITS}"
                )
            if split.instructions not in ("seen", "unseen"):
                raise DatasetConfigError(f"{split.name}: instruction style is 'seen' or 'unseen'")


def make_config(train: int = 2000, test: int = 400, seed: int = 0, dev: int = 0) -> DatasetConfig:
    """The paper's layout with `train` training scenes and `test` scenes per test subset (unseen_cat too), and
    `dev` scenes per dev split (none by default: a dataset without them is the paper's)."""
    table = round(train * 450 / 2000)
    train_levels = (("table", table), ("1obj", table), ("2obj", train - 2 * table))
    dev_splits = (
        SplitConfig("dev_seen", _test_levels(dev), "seen", "seen", "seen"),
        SplitConfig("dev_colour", _test_levels(dev), COLOUR_VARIANTS, "seen", "seen"),
    )
    return DatasetConfig(
        splits=(
            SplitConfig("train", train_levels, "seen", "seen", "seen"),
            SplitConfig("seen", _test_levels(test), "seen", "seen", "seen"),
            SplitConfig("unseen_obj", _test_levels(test), "unseen", "unseen", "seen"),
            SplitConfig("unseen_inst", _test_levels(test), "seen", "seen", "unseen"),
            SplitConfig("unseen_cat", _test_levels(test), "unseen_cat", "unseen", "seen"),
            *(dev_splits if dev > 0 else ()),
        ),
        seed=seed,
    )


def catalogue_config(
    record: dict, subsets: tuple[str, ...], test: int, seed: int = 0, distractors=None
) -> DatasetConfig:
    """A test-only dataset of a user's catalogue (no training split): per subset `test` scenes in the test subsets'
    9:9:22 level mix, on the unseen table textures, with the seen instruction templates, as unseen_obj is made."""
    return DatasetConfig(
        splits=tuple(SplitConfig(name, _test_levels(test), name, "unseen", "seen") for name in subsets),
        seed=seed,
        catalogue=record,
        distractors=distractors,
    )


def default_config() -> DatasetConfig:
    """The paper's: 2000 training scenes (450/450/1100), test subsets of 400 (90/90/220): the paper's three
    and unseen_cat."""
    return make_config()


SMOKE_SIZES = (12, 8)  # training scenes, scenes per test subset


def smoke_config() -> DatasetConfig:
    """A few scenes of every split and level, for tests and CI."""
    return make_config(*SMOKE_SIZES)
