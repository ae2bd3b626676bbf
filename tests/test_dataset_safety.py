"""Names read from a dataset's files never lead outside it, and readers take only what the manifest lists."""

import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ocplace.cli import main
from ocplace.errors import DatasetError
from ocplace.paths import inside
from ocplace.sim.dataset.config import DatasetConfig, SplitConfig, smoke_config
from ocplace.sim.dataset.generate import describe
from ocplace.sim.dataset.job import (
    CONFIG_FILE,
    MANIFEST_FILE,
    generate_dataset,
    listed_scenes,
    scene_dirs,
    verify_dataset,
)
from ocplace.sim.dataset.loader import batches, iter_examples
from ocplace.sim.dataset.records import read_scene

CONFIG = DatasetConfig(splits=(SplitConfig("train", (("table", 1), ("1obj", 1)), "seen", "seen", "seen"),))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, library):
    """Two generated scenes: the smallest real dataset."""
    out = tmp_path_factory.mktemp("tiny") / "ds"
    generate_dataset(out, CONFIG, progress=False)
    return out


def _sandbox(base: Path, tiny: Path) -> Path:
    """`base/trav/a/b/ds`, a copy of `tiny`, with canaries beside and above it and symlinks out of it."""
    ds = base / "trav" / "a" / "b" / "ds"
    shutil.copytree(tiny, ds)
    a = base / "trav" / "a"
    (a / "canary.txt").write_text("keep me")
    (a / "b" / "scene.json").write_text("keep me too")
    for folder in (a / "outside", a / "evil-00000"):  # what a symlinked scene or split would reach
        shutil.copytree(tiny / "train" / "train-00000", folder)
    (ds / "train" / "train-00009").symlink_to(a / "outside")
    (ds / "evil").symlink_to(a)
    return ds


def _snapshot(root: Path) -> dict:
    """Every path under `root` with its size and mtime, symlinks not followed."""
    found = {}
    for top, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            stat = (Path(top) / name).lstat()
            found[(Path(top) / name).relative_to(root).as_posix()] = (stat.st_size, stat.st_mtime_ns)
    return found


def _refusal(call) -> str:
    """The DatasetError message `call` raises, or "" (so that a test can check the files first)."""
    try:
        call()
    except DatasetError as error:
        return str(error)
    return ""


def _with_entries(ds: Path, tiny: Path, entries) -> None:
    manifest = json.loads((tiny / MANIFEST_FILE).read_text())
    manifest["files"] |= {entry: "0" * 64 for entry in entries}
    (ds / MANIFEST_FILE).write_text(json.dumps(manifest))


HOSTILE = [
    "../scene.json",
    "../../x",
    "../../canary.txt",
    "scene.json",
    "train/train-00000/../../../canary.txt",
    "train/train-00009/scene.json",
    "evil/evil-00000/scene.json",
    "train/train-00000/../../ds/x",
]


@pytest.mark.parametrize("entry", [*HOSTILE, "ABSOLUTE"])
def test_a_hostile_manifest_entry_is_refused_and_nothing_is_touched(tmp_path, tiny, entry, capsys):
    ds = _sandbox(tmp_path, tiny)
    entry = str(tmp_path / "trav" / "a" / "canary.txt") if entry == "ABSOLUTE" else entry
    _with_entries(ds, tiny, [entry])
    before = _snapshot(tmp_path)
    refusals = [
        _refusal(lambda: generate_dataset(ds, CONFIG, progress=False)),
        _refusal(lambda: verify_dataset(ds)),
        _refusal(lambda: list(iter_examples(ds, "train"))),
    ]
    code = main(["dataset", "verify", str(ds)])
    assert _snapshot(tmp_path) == before
    assert all(refusal.startswith("corrupt dataset") and repr(entry) in refusal for refusal in refusals), refusals
    assert code == 2 and "ocplace dataset: error: corrupt dataset" in capsys.readouterr().err


def test_cli_generate_refuses_a_traversal_manifest_with_exit_2(tmp_path, capsys):
    """The reported attack: `--out trav/a/b/ds` with `../scene.json` listed; no scene is made."""
    ds = tmp_path / "trav" / "a" / "b" / "ds"
    ds.mkdir(parents=True)
    (tmp_path / "trav" / "a" / "canary.txt").write_text("keep me")
    (ds / CONFIG_FILE).write_text(json.dumps({"config": describe(smoke_config())}))
    (ds / MANIFEST_FILE).write_text(json.dumps({"files": {"../scene.json": "0" * 64}}))
    before = _snapshot(tmp_path)
    code = main(["generate", "--out", str(ds), "--smoke", "--workers", "1"])
    assert _snapshot(tmp_path) == before
    assert code == 2 and "ocplace generate: error: corrupt dataset" in capsys.readouterr().err


_SEGMENTS = st.sampled_from(
    [
        "..",
        ".",
        "",
        "train",
        "train-00000",
        "train-00009",
        "evil",
        "evil-00000",
        "ds",
        "scene.json",
        "rgb.png",
        "canary.txt",
        "x",
    ]
)
_PATHS = st.lists(_SEGMENTS, min_size=1, max_size=6).map("/".join)
_HOSTILE = st.one_of(
    st.sampled_from(HOSTILE),
    _PATHS.map(lambda path: f"../{path}"),  # a `..` segment
    _PATHS.map(lambda path: f"{path}/../.."),
    _PATHS.map(lambda path: f"/{path}"),  # absolute
    st.sampled_from(["train/train-00009", "evil/evil-00000"]).flatmap(  # under a symlink out of the dataset
        lambda folder: st.sampled_from(["scene.json", "rgb.png", "depth.png"]).map(lambda name: f"{folder}/{name}")
    ),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(hostile=st.lists(_HOSTILE, min_size=1, max_size=3), noise=st.lists(_PATHS, max_size=3))
def test_no_hostile_manifest_touches_a_file_outside_the_dataset(tiny, hostile, noise):
    with tempfile.TemporaryDirectory() as base:
        base = Path(base)
        ds = _sandbox(base, tiny)
        _with_entries(ds, tiny, [*noise, *hostile])
        before = _snapshot(base)  # the dataset's parent tree and the dataset itself: nothing may change
        refusals = [
            _refusal(lambda: generate_dataset(ds, CONFIG, progress=False)),
            _refusal(lambda: verify_dataset(ds)),
        ]
        assert _snapshot(base) == before
        assert all(refusals), refusals


def test_inside_refuses_every_way_out(tmp_path):
    root = tmp_path / "root"
    (root / "a").mkdir(parents=True)
    (root / "in").symlink_to(root / "a")
    (root / "out").symlink_to(tmp_path)
    (root / "self").symlink_to(root)
    assert inside(root, "a/b") == root / "a" / "b"
    assert inside(root, "in/b") == root / "in" / "b"  # a symlink that stays inside is fine
    for bad in (
        "",
        ".",
        "./",
        "/etc/passwd",
        str(root / "a"),
        "..",
        "../root/a",
        "a/../../x",
        "a/..",
        "out/x",
        "self",
        None,
    ):
        with pytest.raises(ValueError):
            inside(root, bad)


def test_unlisted_scenes_and_files_are_reported_and_never_read(tmp_path, tiny, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(tiny, ds)
    shutil.copytree(ds / "train" / "train-00000", ds / "train" / "train-00099")
    (ds / "train" / "train-00001" / "notes.txt").write_text("mine")
    (ds / "seen").mkdir()
    (ds / "train" / ".tmp-train-00003-1").mkdir()  # a killed run's leftover: removed by the next run
    problems = dict(verify_dataset(ds))
    assert set(problems) == {"train/train-00099", "train/train-00001/notes.txt", "seen"}
    assert all("not in the manifest" in problem for problem in problems.values())
    assert [d.name for d in scene_dirs(ds, "train")] == ["train-00000", "train-00001"]
    assert [example.scene_id for example in iter_examples(ds, "train", crop_size=32)] == ["train-00000", "train-00001"]
    assert main(["dataset", "verify", str(ds)]) == 1
    assert "train/train-00099 is not in the manifest" in capsys.readouterr().out
    manifest = generate_dataset(ds, CONFIG, progress=False)  # a resume lists only the config's scenes...
    assert manifest["files"] == json.loads((tiny / MANIFEST_FILE).read_text())["files"]
    assert (ds / "train" / "train-00099" / "scene.json").is_file()  # ...and deletes nothing it did not write


@pytest.mark.parametrize(
    "text",
    [
        "[]",
        '"a string"',
        '{"files": ',
        "{}",
        '{"files": ["train/train-00000/rgb.png"]}',
        '{"files": {"train/train-00000/rgb.png": 3}}',
    ],
)
def test_a_manifest_that_is_not_a_manifest_is_a_corrupt_dataset(tmp_path, tiny, text):
    from ocplace.eval.results import dataset_identity
    from ocplace.sim.dataset.identity import dataset_hash

    ds = tmp_path / "ds"
    shutil.copytree(tiny, ds)
    (ds / MANIFEST_FILE).write_text(text)
    before = _snapshot(tmp_path)
    for read in (
        verify_dataset,
        lambda d: generate_dataset(d, CONFIG, progress=False),
        lambda d: list(iter_examples(d, "train")),
        lambda d: dataset_hash(d, "train"),
        dataset_identity,
    ):
        with pytest.raises(DatasetError, match=r"corrupt dataset: .* rerun `ocplace generate --out"):
            read(ds)
    assert _snapshot(tmp_path) == before


# --- scenes edited after generation -----------------------------------------------------------

SEEN = DatasetConfig(splits=(SplitConfig("seen", (("1obj", 2),), "seen", "seen", "seen"),))


@pytest.fixture(scope="module")
def two_seen(tmp_path_factory, library):
    """Two generated scenes of a test subset."""
    out = tmp_path_factory.mktemp("two_seen") / "ds"
    generate_dataset(out, SEEN, progress=False)
    return out


def _edit(path: Path) -> None:
    """A valid file with other content: the scene another instruction, an image one pixel changed."""
    if path.suffix == ".json":
        meta = json.loads(path.read_text())
        meta["instruction"] = "put it at the back left corner of the table"
        path.write_text(json.dumps(meta, indent=1, sort_keys=True))
        return
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    image.flat[0] ^= 1
    cv2.imwrite(str(path), image)


@pytest.mark.parametrize("name", ["scene.json", "rgb.png", "depth.png", "segmentation.png"])
def test_a_scene_edited_after_generation_is_never_read_as_the_datasets(tmp_path, two_seen, name):
    ds = tmp_path / "ds"
    shutil.copytree(two_seen, ds)
    _edit(ds / "seen" / "seen-00001" / name)
    first, second = listed_scenes(ds, "seen")
    record = first.read()  # the untouched scene reads as before, and as an unchecked read does
    for field in ("rgb", "depth", "segmentation"):
        assert np.array_equal(getattr(record, field), getattr(read_scene(first.dir), field))
    readers = [second.read, lambda: list(iter_examples(ds, "seen", 32)), lambda: list(batches(ds, "seen", 2, 32))]
    for read in readers + ([second.info] if name == "scene.json" else []):
        with pytest.raises(DatasetError, match=f"{name} of scene seen-00001 does not match the sha256") as raised:
            read()
        assert f"`ocplace dataset verify --dataset {ds}`" in str(raised.value)


def test_evaluate_refuses_an_edited_scene(tmp_path, two_seen, monkeypatch, capsys):
    import eval_methods

    from ocplace.methods import registry

    monkeypatch.setattr(registry, "method_specs", lambda: dict(eval_methods.SPECS))
    ds = tmp_path / "ds"
    shutil.copytree(two_seen, ds)
    _edit(ds / "seen" / "seen-00001" / "scene.json")
    command = ["evaluate", "--methods", "centre", "--backbone", "none", "--subsets", "seen", "--physical", "0"]
    command += ["--num-samples", "4", "--no-progress", "--workers", "1"]
    assert main([*command, "--dataset", str(two_seen), "--out", str(tmp_path / "published.json")]) == 0
    capsys.readouterr()
    assert main([*command, "--dataset", str(ds), "--out", str(tmp_path / "edited.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ocplace evaluate: error: scene.json of scene seen-00001 does not match the sha256")
    assert "ocplace dataset verify" in err and not (tmp_path / "edited.json").exists()


def test_a_split_that_does_not_exist_is_named_as_such_not_as_a_command_that_fails(smoke_dataset):
    """Issue 44's papercut, on 43's list: `split="test"` advised `ocplace generate --split test`, which argparse
    rejects; a real split missing from the folder still gets the command that makes it."""
    from ocplace.errors import DatasetError
    from ocplace.sim.dataset.job import listed_scenes

    with pytest.raises(DatasetError, match=r"'test' is no split of the benchmark \(they are train, seen") as error:
        listed_scenes(smoke_dataset, "test")
    assert "--split test" not in str(error.value)
    with pytest.raises(DatasetError, match="generate them with `ocplace generate --out .* --split dev_seen`"):
        listed_scenes(smoke_dataset, "dev_seen")


def test_dataset_show_checks_the_scene_against_the_manifest(tmp_path, tiny, capsys):
    """Issue 43's decision: `dataset show` read a scene without the manifest's hashes; an edited scene was drawn."""
    from ocplace.cli import main

    ds = tmp_path / "ds"
    shutil.copytree(tiny, ds)
    scene = sorted((ds / "train").iterdir())[0]
    out = tmp_path / "scene.png"
    command = ["dataset", "show", "--dataset", str(ds), "--out", str(out), "--id"]
    assert main([*command, scene.name]) == 0 and out.is_file()
    meta = scene / "scene.json"
    meta.write_text(meta.read_text() + " ")  # one byte more: the hash no longer matches
    out.unlink()
    assert main([*command, scene.name]) == 2
    assert scene.name in capsys.readouterr().err and not out.exists()
    assert main([*command, "train-99999"]) == 2
    assert "lists no scene 'train-99999'" in capsys.readouterr().err
