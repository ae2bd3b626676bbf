"""The benchmark's names and fixed numbers, each defined once.

A leaf module, cheap to import (the CLI builds its choices from it); it imports nothing from ocplace.
"""

# seen: training (and pretraining) objects; unseen: the unseen_obj test subset's objects, mostly
# new instances of seen categories; unseen_cat: objects of categories no seen object belongs to
# (docs/library.md states the rule).
LIBRARY_SPLITS = ("seen", "unseen", "unseen_cat")
TEXTURE_SPLITS = ("seen", "unseen")  # table textures; unseen_cat scenes use the unseen ones
# Object pools a dataset split draws from: the library splits, and the seen colour variants (the rule is
# `sim.library.library.colour_variants`), the objects of the dev_colour split.
COLOUR_VARIANTS = "seen_colour"
OBJECT_POOLS = (*LIBRARY_SPLITS, COLOUR_VARIANTS)

PAPER_SUBSETS = ("seen", "unseen_obj", "unseen_inst")  # Table I's three test subsets
# Ours, not the paper's: objects of categories no training object belongs to (docs/dataset.md).
TEST_SUBSETS = (*PAPER_SUBSETS, "unseen_cat")

# Development splits: every setting is chosen on them (or on training data), never on a test subset. Their
# scenes come from seed streams of their own (sim/dataset/config.py, SPLIT_NAMES); docs/dataset.md, docs/settings.md.
# dev_seen: seen objects on seen tables; dev_colour: only the seen colour variants (a known-category,
# new-instance proxy for unseen_obj when the selection run's adapters never saw them).
DEV_SPLITS = ("dev_seen", "dev_colour")

# What an evaluation may score: the test subsets (Table I) and the dev splits (choices).
SCORED_SPLITS = (*TEST_SUBSETS, *DEV_SPLITS)

LEVELS = ("table", "1obj", "2obj")  # instruction levels by number of object references, as in the paper

# The parser accepts instructions with more tuples than the benchmark writes, so models pad to this many.
MAX_PARSED_TUPLES = 4
# How the policy chooses each reference's token (models/inference_settings.py): the paper's argmax, or jointly
# among each reference's top_k tokens (at most MAX_TOP_K).
DECISION_MODES = ("argmax", "joint")
MAX_TOP_K = 16
# The benchmark's instructions have at most two tuples (the 2obj level), so models trained only on it pad to this.
MAX_INSTRUCTION_TUPLES = 2

# OpenAI CLIP's per-channel pixel statistics (RGB, on [0, 1]): CLIP-style towers were trained on inputs normalised so.
CLIP_IMAGE_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_IMAGE_STD = (0.26862954, 0.26130258, 0.27577711)

# The robot's refusal gate (`PlacementPolicy.threshold`, `ocplace place`): a scene is refused when a reference's
# best visual token has a lower probability. Table I places always (the paper's protocol); the gate is reported
# beside it (eval/statistics.py). Chosen on the dev splits, never on a test subset: docs/settings.md.
GATE_THRESHOLD = 0.55

# The experiments of configs/ by name (the keys of `ocplace.configs.EXPERIMENTS`), for the CLI's choices.
EXPERIMENT_NAMES = ("smoke", "demo", "default")

# The named primitives of the backbone's pretraining arenas (`sim/primitives.py`): shapes and sizes.
SHAPES = ("box", "cylinder", "sphere", "cone", "ring", "disc", "capsule", "pyramid")
SIZES = ("small", "medium", "large")
# What captions call each shape (its first word is the shape's own name).
SHAPE_WORDS = {
    "box": ("box", "cube", "block"),
    "cylinder": ("cylinder",),
    "sphere": ("sphere", "ball"),
    "cone": ("cone",),
    "ring": ("ring", "torus"),
    "disc": ("disc", "disk", "plate-like disc"),
    "capsule": ("capsule", "pill"),
    "pyramid": ("pyramid",),
}


# A subset of a user's own catalogue (docs/library.md, "Test on your own objects") is named like this, and never
# like a split, pool or level of the benchmark's.
OWN_SUBSET_PATTERN = r"[a-z][a-z0-9_]{0,47}"
RESERVED_NAMES = frozenset((*SCORED_SPLITS, *OBJECT_POOLS, "train", "all", *LEVELS))


def is_own_subset(name: object) -> bool:
    """Whether `name` can be a subset of a user's catalogue (which a dataset then may or may not hold)."""
    import re

    return isinstance(name, str) and re.fullmatch(OWN_SUBSET_PATTERN, name) is not None and name not in RESERVED_NAMES


def subsets_problem(subsets, key: str, allowed: tuple[str, ...] = SCORED_SPLITS) -> str | None:
    """What is wrong with `subsets` as the splits to score (none, unknown or repeated), named by `key`; a subset of
    a user's catalogue is allowed where dev splits are."""
    own = allowed == SCORED_SPLITS
    unknown = [subset for subset in subsets if subset not in allowed and not (own and is_own_subset(subset))]
    if unknown or not subsets or len(set(subsets)) < len(subsets):
        kinds = "test subset, dev split or subset of your catalogue" if own else "test subset"
        named = ", ".join(subsets) or "none"
        return f"{key} must name each {kinds} at most once, some of {', '.join(allowed)}; got {named}"
    return None


# Placement samples per scene anything accepts: `(scenes, samples, 2)` arrays and XLA's buffers for them stay small
# (200,000,000 aborted an evaluation worker inside XLA). The paper draws 1,024.
MAX_SAMPLES = 65_536
MAX_SEED = 2**32 - 1  # numpy's seeds are 32-bit; a seed above would be refused (or wrap) deep in a task

# Seconds anyone's policy (`evaluate --policy`) may take per scene before that scene fails as a timeout.
SCENE_TIMEOUT_S = 60.0

# The file formats figures are written in (`ocplace figures --format`; models/placement/figures.py `FigureStyle`).
FIGURE_FORMATS = ("png", "pdf", "svg")

# Object nouns that are plural (a pair, a set): captions say "a photo of scissors", never "of a scissors".
PLURAL_NOUNS = frozenset(
    (
        "scissors",
        "pliers",
        "tongs",
        "tweezers",
        "glasses",
        "sunglasses",
        "goggles",
        "headphones",
        "earphones",
        "earbuds",
        "binoculars",
        "shears",
        "clippers",
        "chopsticks",
        "sneakers",
        "shoes",
        "boots",
        "socks",
        "gloves",
        "mittens",
        "jeans",
        "trousers",
        "pants",
        "shorts",
        "dice",
        "keys",
        "grapes",
    )
)
