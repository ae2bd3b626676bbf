"""What an installed ocplace says about itself: its cache root and its version (docs/install.md)."""

import subprocess
import sys
from importlib import metadata
from pathlib import Path

import ocplace
from ocplace.eval.table import render
from ocplace.paths import cache_dir


def test_the_cache_is_ocplace_cache_else_the_xdg_user_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "mine"
    monkeypatch.delenv("OCPLACE_CACHE")
    assert cache_dir() == tmp_path / "xdg" / "ocplace"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_dir() == Path.home() / ".cache" / "ocplace"


def test_the_version_is_the_installed_packages():
    assert ocplace.__version__ == metadata.version("ocplace")
    printed = subprocess.run([sys.executable, "-m", "ocplace.cli", "--version"], capture_output=True, text=True)
    assert printed.stdout.strip() == f"ocplace {metadata.version('ocplace')}", printed.stderr


def test_results_of_an_install_without_git_name_its_version(tmp_path):
    environment = {"ocplace": "0.1.0", "git": {"commit": None, "dirty": None}}
    results = {
        "dataset": {"dataset_hash": "0" * 16, "dir": str(tmp_path)},
        "settings": {"backbone": "offline", "parser": "offline", "num_samples": 8, "seed": 0, "subsets": ["seen"]},
        "environment": environment,
        "evaluations": [],
    }
    assert "; ocplace 0.1.0." in render(results)
