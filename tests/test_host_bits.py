"""Issue 58, item 8: what another x86-64 host would vary, varied here: the software renderer's CPU features
(`GALLIUM_OVERRIDE_CPU_CAPS`) and XLA's instruction set (`--xla_cpu_max_isa`), down to AVX2 with FMA, the baseline
of the machines ocplace has run on. A rendered scene and the offline backbone's features must keep their bits
(docs/performance.md, "Bits across machines", says what parts below it). Slow: each variant is a fresh process."""

import hashlib
import os
import subprocess
import sys

import pytest

RENDER = """
import hashlib, sys
import numpy as np
from ocplace.sim.library import load_library
from ocplace.sim.mujoco_backend import MujocoScenes
from ocplace.sim.scene import render_sampled_scene
library = load_library()
with MujocoScenes.from_library(library) as arena:
    scene = render_sampled_scene(library, arena, 3, "seen")
print(hashlib.sha256(np.ascontiguousarray(scene.rgb).tobytes() + scene.depth.tobytes()).hexdigest())
"""

FEATURES = """
import hashlib, sys
import jax
import numpy as np
from ocplace.models import offline_backbone, offline_config
config = offline_config.smoke_config()
backbone = offline_backbone.OfflineBackbone(config, offline_backbone.init_params(config, jax.random.key(0)))
images = np.random.default_rng(0).integers(0, 256, (8, 96, 96, 3), dtype=np.uint8)
features = np.concatenate([backbone.encode_images(images), backbone.encode_texts(["a red bowl", "the table"])])
print(hashlib.sha256(features.astype(np.float32).tobytes()).hexdigest())
"""


def _digest(script: str, **env: str) -> str:
    done = subprocess.run(
        [sys.executable, "-c", script], env=os.environ | env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.slow
@pytest.mark.parametrize("caps", ["avx2", "avx"])
def test_a_rendered_scene_keeps_its_bytes_on_a_host_with_fewer_cpu_features(library, caps):
    assert _digest(RENDER) == _digest(RENDER, GALLIUM_OVERRIDE_CPU_CAPS=caps)


@pytest.mark.slow
def test_the_offline_backbones_features_keep_their_bits_at_avx2():
    native = _digest(FEATURES)
    assert native == _digest(FEATURES, XLA_FLAGS="--xla_cpu_max_isa=AVX2")
    assert len(native) == len(hashlib.sha256().hexdigest())
