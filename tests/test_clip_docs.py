"""docs/clip.md's shell blocks run as written, in order, on a tiny random CLIP checkpoint (slow: a smoke `reproduce`
from nothing). The Python block that writes a checkpoint needs the hub and is not run: `build_tiny_clip` writes the
same files with the same calls."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from tiny_clip import build_tiny_clip

DOC = Path(__file__).resolve().parents[1] / "docs" / "clip.md"


@pytest.mark.slow
def test_the_clip_walkthrough_runs_as_written(tmp_path, tokenizer_dir, borrowed_cache):
    checkpoint = build_tiny_clip(tmp_path / "clip", seed=5, tokenizer_dir=tokenizer_dir)
    blocks = re.findall(r"```bash\n(.*?)```", DOC.read_text(), re.S)
    assert len(blocks) == 3, "docs/clip.md's shell blocks changed: check this test runs each"
    env = os.environ | {"CLIP": str(checkpoint), "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    for line in [line for block in blocks for line in block.splitlines() if line.strip()]:
        done = subprocess.run(["bash", "-euo", "pipefail", "-c", line], cwd=tmp_path, env=env, capture_output=True)
        refused = line.startswith("ocplace place") and done.returncode == 2  # the tiny random model may refuse
        assert done.returncode == 0 or refused, (line, done.stderr.decode()[-3000:])
    assert (tmp_path / "out/clip/results.json").is_file() and (tmp_path / "out/clip/runs.json").is_file()
    assert (tmp_path / "out/clip/exported/config.json").is_file()
