"""The benchmark's names and fixed numbers, each defined once.

A leaf module, cheap to import (the CLI builds its choices from it); it imports nothing from ocplace.
"""

# seen: training (and pretraining) objects; unseen: the unseen_obj test subset's objects, mostly
# new instances of seen categories; unseen_cat: objects of categories no seen object belongs to
# (docs/library.md states the rule).
LIBRARY_SPLITS = ("seen", "unseen", "unseen_cat")
TEXTURE_SPLITS = ("seen", "unseen")  # table textures; unseen_cat scenes use the unseen ones

PAPER_SUBSETS = ("seen", "unseen_obj", "unseen_inst")  # Table I's three test subsets
# Ours, not the paper's: objects of categories no training object belongs to (docs/dataset.md).
TEST_SUBSETS = (*PAPER_SUBSETS, "unseen_cat")

LEVELS = ("table", "1obj", "2obj")  # instruction levels by number of object references, as in the paper

# The parser accepts instructions with more tuples than the benchmark writes, so models pad to this many.
MAX_PARSED_TUPLES = 4
# The benchmark's instructions have at most two tuples (the 2obj level), so models trained only on it pad to this.
MAX_INSTRUCTION_TUPLES = 2

# OpenAI CLIP's per-channel pixel statistics (RGB, on [0, 1]): CLIP-style towers were trained on inputs normalised so.
CLIP_IMAGE_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_IMAGE_STD = (0.26862954, 0.26130258, 0.27577711)

# The experiments of ocplace/configs by name (the keys of `ocplace.configs.EXPERIMENTS`), for the CLI's choices.
EXPERIMENT_NAMES = ("smoke", "demo", "default")

# The named primitives of the backbone's pretraining arenas (`sim/primitives.py`): shapes and sizes.
SHAPES = ("box", "cylinder", "sphere", "cone", "ring", "disc", "capsule", "pyramid")
SIZES = ("small", "medium", "large")


def subsets_problem(subsets, key: str) -> str | None:
    """What is wrong with `subsets` as the test subsets to score (none, unknown or repeated), named by `key`."""
    unknown = [subset for subset in subsets if subset not in TEST_SUBSETS]
    if unknown or not subsets or len(set(subsets)) < len(subsets):
        return (
            f"{key} must name each test subset at most once, some of {', '.join(TEST_SUBSETS)}; "
            f"got {', '.join(subsets) or 'none'}"
        )
    return None
