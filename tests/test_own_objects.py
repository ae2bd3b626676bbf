"""Issue 59: a lab's own objects in a catalogue it writes, a test-only dataset of its subsets, scored under their
names, with no leakage into the benchmark's pools or the backbone's key. Real meshes (made by
scripts/example_catalogue.py), real builds, real MuJoCo scenes, a real evaluation."""

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from example_catalogue import OBJECTS, write_example


def _catalogue(folder: Path, name: str = "lab", **changes) -> Path:
    """The example catalogue in `folder`, renamed `name` (a name per test: xdist workers share no catalogue)."""
    path = write_example(folder)
    data = json.loads(path.read_text())
    data["name"] = name
    data["subsets"] = {name: {"new_categories": True}}
    data |= changes
    path.write_text(json.dumps(data))
    return path


def test_every_problem_of_a_catalogue_is_listed_before_any_work(tmp_path, borrowed_cache):
    """The issue's bad input, all in one file: one CatalogueError naming each, nothing built."""
    from ocplace.errors import CatalogueError
    from ocplace.sim.library.user_catalogue import read_catalogue

    path = _catalogue(tmp_path / "objects", "lab_bad")
    folder = path.parent
    (folder / "notes.obj").write_text("these are not triangles\n")
    (folder / "loop_a.obj").symlink_to("loop_b.obj")
    (folder / "loop_b.obj").symlink_to("loop_a.obj")
    shutil.copy(folder / "meshes" / "lab_puck.obj", tmp_path / "outside.obj")
    data = json.loads(path.read_text())
    good = data["objects"][0]
    data["subsets"]["unseen_obj"] = {}
    data["objects"] += [
        dict(good),  # a duplicate name
        good | {"name": "gone", "human_name": "gone", "mesh": "meshes/missing.obj"},
        good | {"name": "notes", "human_name": "notes", "mesh": "notes.obj"},
        good | {"name": "huge", "human_name": "huge", "units": "m"},  # 110 m across
        good | {"name": "tinted", "human_name": "tinted", "rgba": [1.5, 0, 0]},
        {k: v for k, v in good.items() if k != "licence"} | {"name": "unlicensed", "human_name": "unlicensed"},
        good | {"name": "escapes", "human_name": "escapes", "mesh": "../outside.obj"},
        good | {"name": "looped", "human_name": "looped", "mesh": "loop_a.obj"},
        good | {"name": "a_mug", "human_name": "my mug", "category": "mug"},  # a training category, new_categories
    ]
    path.write_text(json.dumps(data))
    with pytest.raises(CatalogueError) as error:
        read_catalogue(path)
    message = str(error.value)
    for expected in (
        "'unseen_obj' is a name of the benchmark's",
        "lab_canister: listed 2 times",
        "'meshes/missing.obj' does not exist",
        "notes.obj holds no triangles",
        '110 m across, outside a tabletop object\'s 0.005-0.6 m: its mesh is 110 units across; set "units": "mm"',
        "rgba: three or four numbers in [0, 1]",
        "(unlicensed): licence: missing",
        "'../outside.obj' leads out of the catalogue's folder",
        "'loop_a.obj' cannot be resolved",
        "category 'mug' has training objects",
    ):
        assert expected in message, expected
    assert "nothing was built" in message and message.count("\n  - ") == 10
    assert not (borrowed_cache / "catalogues").exists()


def test_a_catalogue_never_enters_the_benchmark_pools_or_the_backbone_key(tmp_path, borrowed_cache):
    """Building a catalogue leaves the library manifest, its pools and the backbone's cache key as they were; a
    library whose pool differs (an object added with --gso) gets another key."""
    from ocplace.models.offline_recipes import recipe_dir
    from ocplace.sim.library import default_config, load_library
    from ocplace.sim.library.build import build_catalogue
    from ocplace.sim.library.library import added_objects_digest
    from ocplace.sim.library.user_catalogue import read_catalogue

    manifest = borrowed_cache / "library" / "manifest.json"
    before = (manifest.read_bytes(), {s: load_library().names(s) for s in ("seen", "unseen", "unseen_cat")})
    keys = {recipe: recipe_dir(recipe) for recipe in ("default", "demo")}
    built = build_catalogue(
        read_catalogue(_catalogue(tmp_path / "objects", "lab_pools")), default_config(), progress=False
    )
    assert sorted(built.objects) == sorted(entry[0] for entry in OBJECTS)
    assert before == (manifest.read_bytes(), {s: load_library().names(s) for s in ("seen", "unseen", "unseen_cat")})
    assert keys == {recipe: recipe_dir(recipe) for recipe in keys} and added_objects_digest() == ""

    changed = borrowed_cache / "changed"
    (changed / "library").mkdir(parents=True)
    data = json.loads(manifest.read_text())
    data["objects"].append(dict(data["objects"][0], name="my_scan", split="seen", folder="objects/my_scan-0"))
    (changed / "library" / "manifest.json").write_text(json.dumps(data))
    assert added_objects_digest(changed) != ""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OCPLACE_CACHE", str(changed))
        assert recipe_dir("default").name.startswith(keys["default"].name + "-pool")


@pytest.mark.slow  # the default suite's 15 min budget on 2 cores (docs/performance.md)
def test_the_same_catalogue_from_two_folders_is_the_same_objects_and_dataset(tmp_path, borrowed_cache):
    """Identity by content: object keys, recorded sources and the dataset hash never hold where the files lie."""
    from ocplace.eval.results import dataset_identity
    from ocplace.sim.dataset.config import catalogue_config
    from ocplace.sim.dataset.job import generate_dataset
    from ocplace.sim.library import default_config
    from ocplace.sim.library.build import build_catalogue
    from ocplace.sim.library.catalogue_library import catalogue_record
    from ocplace.sim.library.user_catalogue import read_catalogue

    identities = []
    for copy in ("first", "second"):
        catalogue = read_catalogue(_catalogue(tmp_path / copy / "my objects", "lab_twice"))
        library = build_catalogue(catalogue, default_config(), progress=False)
        folders = sorted(asset.directory.name for asset in library.objects.values())
        config = catalogue_config(catalogue_record(catalogue), ("lab_twice",), test=4)
        generate_dataset(tmp_path / copy / "dataset", config, progress=False)
        scene = json.loads((tmp_path / copy / "dataset" / "lab_twice" / "lab_twice-00000" / "scene.json").read_text())
        identities.append(
            (catalogue.content_hash, folders, dataset_identity(tmp_path / copy / "dataset")["dataset_hash"])
        )
        assert all(str(tmp_path) not in obj["asset"] for obj in scene["objects"])
        assert {obj["name"] for obj in scene["objects"]} <= set(library.objects)  # only the catalogue's objects
    assert identities[0] == identities[1]


@pytest.mark.slow  # the default suite's 15 min budget on 2 cores (docs/performance.md)
def test_from_meshes_to_a_table_one_column_in_three_commands(tmp_path, default_offline_backbone, capsys):
    """`assets build --catalogue`, `generate --catalogue`, `evaluate --subsets`: a test-only dataset (no training
    split), scored under the subset's name, the results naming the catalogue by content hash."""
    from ocplace.cli import main

    path = _catalogue(tmp_path / "objects", "lab_e2e")
    assert main(["assets", "build", "--catalogue", str(path), "--workers", "1"]) == 0
    assert main(["generate", "--out", str(tmp_path / "ds"), "--catalogue", str(path), "--test", "4"]) == 0
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert set(manifest["counts"]) == {"lab_e2e"} and not any(f.startswith("train/") for f in manifest["files"])
    out = tmp_path / "results.json"
    capsys.readouterr()
    code = main(
        ["evaluate", "--dataset", str(tmp_path / "ds"), "--methods", "no_adapter", "--subsets", "lab_e2e"]
        + ["--out", str(out), "--physical", "2", "--workers", "1"]
    )
    assert code == 0
    results = json.loads(out.read_text())
    scored = results["evaluations"][0]["subsets"]["lab_e2e"]
    assert len(scored["scenes"]) == 4 and results["dataset"]["config"]["catalogue"]["name"] == "lab_e2e"
    assert scored["aggregate"]["overall"]["physical_scenes"] == 2
    markdown = out.with_suffix(".md").read_text()
    content = results["dataset"]["config"]["catalogue"]["content_hash"][:16]
    assert "lab_e2e (your objects)" in markdown and f"of your catalogue `lab_e2e` (content {content})" in markdown


def test_a_catalogue_dataset_is_refused_what_it_cannot_hold(tmp_path, borrowed_cache):
    """Too few objects for a scene, a benchmark flag on a test-only dataset, a catalogue built from other content:
    each refused before any scene, with what to do."""
    from ocplace.cli import main
    from ocplace.errors import CatalogueError, DatasetConfigError
    from ocplace.sim.dataset.config import catalogue_config
    from ocplace.sim.dataset.job import generate_dataset
    from ocplace.sim.library import default_config
    from ocplace.sim.library.build import build_catalogue
    from ocplace.sim.library.catalogue_library import catalogue_record
    from ocplace.sim.library.user_catalogue import read_catalogue

    path = _catalogue(tmp_path / "objects", "lab_small")
    data = json.loads(path.read_text())
    data["objects"] = data["objects"][:3]
    path.write_text(json.dumps(data))
    catalogue = read_catalogue(path)
    build_catalogue(catalogue, default_config(), progress=False)
    with pytest.raises(DatasetConfigError, match="'lab_small' has 3 objects; its scenes need 6.*--distractors unseen"):
        generate_dataset(tmp_path / "ds", catalogue_config(catalogue_record(catalogue), ("lab_small",), 4))
    mixed = catalogue_config(catalogue_record(catalogue), ("lab_small",), 4, distractors="unseen")
    generate_dataset(tmp_path / "mixed", mixed, progress=False)
    scene = json.loads((tmp_path / "mixed" / "lab_small" / "lab_small-00000" / "scene.json").read_text())
    own = {spec.name for spec in catalogue.specs}
    referred = {
        scene["objects"][t["reference_object_id"] - 1]["name"] for t in scene["tuples"] if t["reference_object_id"]
    }
    assert scene["held_object"]["name"] in own and referred <= own  # distractors are never referred to
    assert main(["generate", "--out", str(tmp_path / "x"), "--catalogue", str(path), "--train", "5"]) == 2
    data["objects"][0]["human_name"] = "another name"
    path.write_text(json.dumps(data))
    changed = read_catalogue(path)
    with pytest.raises(CatalogueError, match="is other content .* `ocplace assets build --catalogue FILE`"):
        generate_dataset(tmp_path / "stale", catalogue_config(catalogue_record(changed), ("lab_small",), 4))
    assert not (tmp_path / "ds" / "lab_small").exists() and not (tmp_path / "stale" / "lab_small").exists()


def test_a_plural_object_is_captioned_without_an_article():
    from ocplace.models.backbone import PromptConfig

    prompt = PromptConfig()
    assert prompt.text_for("scissors") == "a photo of scissors."
    assert prompt.text_for("black and blue sneakers") == "a photo of black and blue sneakers."
    assert prompt.text_for("black shoe with orange stripes") == "a photo of a black shoe with orange stripes."
    assert prompt.text_for("red bowl") == "a photo of a red bowl." and prompt.text_for("table") == "a photo of a table."


def test_the_backbones_pretraining_captions_keep_their_words():
    """The demo's backbone changed fingerprint when its captions of corpus models named "boots" or "glasses" lost
    their article under the same recipe key: pretraining captions stay as the recipes were trained."""
    from ocplace.models.backbone import PromptConfig
    from ocplace.train.pretrain.captions import ObjectDescription, object_captions

    boots = ObjectDescription("boots", "boots", (), "boots")
    assert "a photo of a boots." in object_captions(boots, PromptConfig())
    assert PromptConfig().text_for("boots") == "a photo of boots."  # grounding a plural object reads right


@pytest.mark.slow
def test_the_own_objects_tutorial_runs_as_written(tmp_path, trained_run, tiny_backbone_spec, borrowed_cache):
    """docs/library.md's "Test on your own objects" block, line by line, in a folder holding an exported policy where
    the tutorial expects `make demo`'s (the smoke run of Ours on the tiny backbone)."""
    import os
    import re
    import subprocess

    from ocplace.cli import main

    run_dir, _ = trained_run
    policy = tmp_path / "out" / "demo" / "policy"
    assert main(["export", "--run", str(run_dir), "--backbone", tiny_backbone_spec, "--out", str(policy)]) == 0
    (tmp_path / "scripts").symlink_to(Path(__file__).resolve().parents[1] / "scripts")
    text = (Path(__file__).resolve().parents[1] / "docs" / "library.md").read_text()
    section = text[text.index("## Test on your own objects") :]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    env = os.environ | {"PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    lines = [line for line in block.splitlines() if line.strip()]
    assert len(lines) == 4, "the tutorial's commands changed: check this test runs each"
    for line in lines:
        done = subprocess.run(["bash", "-euo", "pipefail", "-c", line], cwd=tmp_path, env=env, capture_output=True)
        assert done.returncode == 0, (line, done.stderr.decode()[-3000:])
    results = json.loads((tmp_path / "out" / "lab" / "results.json").read_text())
    assert len(results["evaluations"][0]["subsets"]["lab"]["scenes"]) == 40
    assert "lab (your objects)" in (tmp_path / "out" / "lab" / "results.md").read_text()


def test_a_failed_object_fails_the_build_and_a_catalogue_can_be_listed_and_removed(tmp_path, borrowed_cache, capsys):
    """`assets build` exits 1 naming each object that failed (a flat sheet has no volume to collide with); `assets
    list` shows category, subset, source and licence; `assets remove` takes a catalogue away, never a benchmark
    object."""
    import numpy as np
    import trimesh

    from ocplace.cli import main

    path = _catalogue(tmp_path / "objects", "lab_fails")
    sheet = trimesh.Trimesh(
        np.array([[0, 0, 0], [90, 0, 0], [90, 60, 0], [0, 60, 0]]), np.array([[0, 1, 2], [0, 2, 3]])
    )
    sheet.export(path.parent / "meshes" / "sheet.obj")
    data = json.loads(path.read_text())
    data["objects"].append(
        data["objects"][0] | {"name": "sheet", "human_name": "paper sheet", "mesh": "meshes/sheet.obj"}
    )
    path.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["assets", "build", "--catalogue", str(path), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert "1 object(s) failed to build" in err and "sheet: " in err
    assert main(["assets", "list", "--catalogue", "lab_fails"]) == 0
    listing = capsys.readouterr().out
    assert "category" in listing and "licence" in listing and "sheet" in listing and "FAILED" in listing
    assert (
        "green canister           canister       lab_fails" in listing
        and "catalogue:meshes/lab_canister.obj" in listing
    )
    assert main(["generate", "--out", str(tmp_path / "ds"), "--catalogue", str(path), "--test", "4"]) == 2
    assert "sheet failed to build" in capsys.readouterr().err and not (tmp_path / "ds" / "lab_fails").exists()
    assert main(["assets", "remove", "alphabet_soup"]) == 2  # the benchmark's own
    assert main(["assets", "remove", "--catalogue", "lab_fails"]) == 0
    assert not (borrowed_cache / "catalogues" / "lab_fails").exists()
