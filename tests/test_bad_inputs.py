"""Invalid inputs are typed errors (exit 2 from the CLI), found before any model loads (docs/reliability.md).

The CLI cases pass `--backbone offline:<missing folder>`: had a command gone past its input checks,
it would stop at loading that backbone with another message, so each expected message also proves
that the check came before the model.
"""

import errno
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ocplace.cli import main
from ocplace.errors import OutputError, ParseError, PolicyInputError, ResultsError
from ocplace.eval.results import read_results, settings_of
from ocplace.models.parsing import as_pairs, make_parser
from ocplace.paths import atomic_path, check_writable
from ocplace.sim.camera import DEFAULT_CAMERA
from ocplace.sim.pinhole import PinholeCamera

NO_MODEL = "offline:/nonexistent/ocplace-backbone"  # loading it fails: reaching it means checks came too late
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _cli(capsys, *argv) -> tuple[int, str, str]:
    """The exit status and output of `ocplace ARGV`: a usage error (a flag refused as it is read) included."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as stop:
        code = stop.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture
def images(tmp_path):
    """A flat, empty table seen by the simulator's camera: rgb PNG, depth .npy (metres), camera JSON."""
    rgb, depth, camera = tmp_path / "rgb.png", tmp_path / "depth.npy", tmp_path / "camera.json"
    cv2.imwrite(str(rgb), np.full((DEFAULT_CAMERA.height, DEFAULT_CAMERA.width, 3), 90, np.uint8))
    np.save(depth, np.full((DEFAULT_CAMERA.height, DEFAULT_CAMERA.width), DEFAULT_CAMERA.position[2], np.float32))
    camera.write_text(json.dumps(DEFAULT_CAMERA.to_json()))
    return {"rgb": rgb, "depth": depth, "camera": camera}


def _place(images, tmp_path, **changes):
    """`ocplace place` arguments on `images`, each option replaceable (None: left out)."""
    options = {
        "rgb": images["rgb"],
        "depth": images["depth"],
        "camera": images["camera"],
        "instruction": "put it on the left",
        "backbone": NO_MODEL,
        "out": tmp_path / "place.png",
        **changes,
    }
    return ["place", *[part for name, value in options.items() if value is not None for part in (f"--{name}", value)]]


def _camera_json(**fields) -> dict:
    """The default camera's JSON with `fields` replaced; fx, fy, cx, cy also go into K, where they live."""
    camera = json.loads(json.dumps(DEFAULT_CAMERA.to_json()))
    for name, index in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}.items():
        if name in fields:
            camera["intrinsics"][index[0]][index[1]] = fields[name]
    camera.update(fields)
    return json.loads(json.dumps(camera))  # through JSON text, as a file would give it (NaN and Infinity too)


# --- the camera ------------------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(fx=FLOATS, fy=FLOATS)
def test_camera_focal_lengths_must_be_positive_and_finite(fx, fy):
    fields = _camera_json(fx=fx, fy=fy)
    if all(math.isfinite(f) and f > 0 for f in (fx, fy)):
        camera = PinholeCamera.from_json(fields)
        assert camera.intrinsics[0, 0] == fx and camera.intrinsics[1, 1] == fy
    else:
        with pytest.raises(PolicyInputError, match="focal length f[xy]|intrinsics must be a 3x3 matrix of finite"):
            PinholeCamera.from_json(fields)


@settings(max_examples=200, deadline=None)
@given(cx=FLOATS, cy=FLOATS, width=st.one_of(st.integers(-5, 5000), FLOATS, st.text(max_size=3), st.none()))
def test_camera_principal_point_and_size(cx, cy, width):
    fields = _camera_json(cx=cx, cy=cy, width=width)
    valid_width = isinstance(width, (int, float)) and math.isfinite(width) and width > 0 and width == int(width)
    if math.isfinite(cx) and math.isfinite(cy) and valid_width:
        assert PinholeCamera.from_json(fields).width == int(width)
    else:
        with pytest.raises(PolicyInputError, match="camera (intrinsics|width)"):
            PinholeCamera.from_json(fields)


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"world_from_camera": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}, "not a rotation"),  # a mirror: left is right
        ({"world_from_camera": (np.eye(4) * 2).tolist()}, "last row"),
        ({"world_from_camera": [[1.0, 0.0], [0.0, 1.0]]}, "world_from_camera must be a 4x4"),
        ({"intrinsics": [[457.0, 0.0, 319.5], [0.0, 457.0, 239.5], [0.0, 1.0, 1.0]]}, "not a pinhole K"),
        ({"height": 0}, "height is 0; it must be a positive whole number"),
        ({"height": 479.5}, "height is 479.5"),
    ],
)
def test_camera_pose_and_size_are_checked(fields, message):
    with pytest.raises(PolicyInputError, match=message):
        PinholeCamera.from_json({**_camera_json(), **fields})


def test_camera_fields_that_repeat_k_must_agree_with_it():
    fields = _camera_json()
    fields["fx"] = -fields["fx"]  # edited beside K, not in it: once silently ignored
    with pytest.raises(PolicyInputError, match="fx = -457.* disagrees with intrinsics\\[0, 0\\]"):
        PinholeCamera.from_json(fields)


@pytest.mark.parametrize(
    "focal, message", [(-457.0, "fx \\(intrinsics\\[0, 0\\]\\) is -457"), (0.0, "fx \\(intrinsics\\[0, 0\\]\\) is 0")]
)
def test_cli_refuses_a_non_positive_focal_length(images, tmp_path, capsys, focal, message):
    images["camera"].write_text(json.dumps(_camera_json(fx=focal)))
    code, out, err = _cli(capsys, *_place(images, tmp_path))
    assert code == 2 and "mode:" not in out
    assert err.startswith("ocplace place: error: camera focal length") and len(err.splitlines()) == 1
    assert re.search(message, err)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "cannot read the camera file .*camera.json: No such file"),
        ('{"intrinsics": [[457.0, 0.0, 319.5], [0.0, 4', "the camera file .* is not valid JSON"),
        ("[1, 2, 3]", "a camera JSON is an object, not list"),
        ('{"width": 640, "height": 480}', "camera JSON lacks \\['intrinsics', 'world_from_camera'\\]"),
    ],
)
def test_cli_refuses_a_missing_or_truncated_camera_file(images, tmp_path, capsys, content, message):
    if content is None:
        images["camera"].unlink()
    else:
        images["camera"].write_text(content)
    code, _, err = _cli(capsys, *_place(images, tmp_path))
    assert code == 2
    assert re.search(f"^ocplace place: error: {message}", err), err


# --- the instruction -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "instruction, relations",
    [
        ("put it to the left and right of the mug", "'left' and 'right' on 'mug'"),
        ("put it to the left and to the right of the mug", "'left' and 'right' on 'mug'"),
        ("put it in front of and behind the mug", "'front' and 'back' on 'mug'"),
        ("put it in the back left and front right corners of the mug", "'back left' and 'front right' on 'mug'"),
        ("put it behind the cup and to the left and right of the bowl", "'left' and 'right' on 'bowl'"),
    ],
)
def test_opposite_relations_on_one_reference_contradict(instruction, relations):
    with pytest.raises(ParseError, match=f"the relations {relations} contradict"):
        make_parser("offline").parse(instruction)


@pytest.mark.parametrize(
    "instruction, expected",
    [
        ("put it to the left of and behind the mug", [("mug", "back left")]),
        ("put it on the left and behind the mug", [("mug", "back left")]),
        ("put it to the left of the mug and to the right of the bowl", [("bowl", "right"), ("mug", "left")]),
        ("put it in the left part of the table and to the right of the lemon", [("lemon", "right"), ("table", "left")]),
    ],
)
def test_relations_that_do_not_contradict_still_parse(instruction, expected):
    assert sorted(as_pairs(make_parser("offline").parse(instruction))) == expected


def test_cli_refuses_a_contradictory_instruction_before_the_model(images, tmp_path, capsys):
    code, _, err = _cli(capsys, *_place(images, tmp_path, instruction="put it to the left and right of the mug"))
    assert code == 2 and err.startswith("ocplace place: error: the relations 'left' and 'right' on 'mug' contradict")


@pytest.mark.parametrize("instruction", ["", "   ", "\t\n"])
def test_cli_refuses_an_empty_instruction(images, tmp_path, capsys, instruction):
    for source in (
        _place(images, tmp_path, instruction=instruction),
        [
            "place",
            "--dataset",
            tmp_path / "no-dataset",
            "--id",
            "0",
            "--instruction",
            instruction,
            "--backbone",
            NO_MODEL,
        ],
    ):  # not the scene's own instruction instead
        code, _, err = _cli(capsys, *source)
        assert code == 2 and err.startswith("ocplace place: error: --instruction is empty"), err


# --- depth files -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "array, message",
    [
        (np.array([{"depth": 0.6}, None], dtype=object), "cannot read the depth .* as a .npy array of numbers"),
        (np.full((480, 640), "far"), "depth must hold numbers .* got dtype <U3"),
        (np.ones((480, 640), bool), "depth must hold numbers .* got dtype bool"),
        (np.ones((480, 640, 3), np.float32), "depth must be an \\(H, W\\) image, got shape \\(480, 640, 3\\)"),
    ],
)
def test_cli_refuses_a_pickled_or_non_numeric_depth(images, tmp_path, capsys, array, message):
    np.save(images["depth"], array, allow_pickle=True)
    code, _, err = _cli(capsys, *_place(images, tmp_path))
    assert code == 2 and re.search(f"^ocplace place: error: {message}", err), err


def test_cli_refuses_a_truncated_or_missing_depth(images, tmp_path, capsys):
    data = images["depth"].read_bytes()
    images["depth"].write_bytes(data[: len(data) // 2])
    code, _, err = _cli(capsys, *_place(images, tmp_path))
    assert code == 2 and "error: cannot read the depth" in err
    code, _, err = _cli(capsys, *_place(images, tmp_path, depth=tmp_path / "missing.npy"))
    assert code == 2 and "error: cannot read the depth" in err and "No such file" in err


@pytest.mark.parametrize(
    "image, size, message",
    [
        ("depth", (320, 240), "rgb is 640x480 but depth is 320x240; register the depth image to the colour image"),
        ("segmentation", (320, 240), "the segmentation (boxes_or_segmentation) has shape (240, 320): pass a "),
        ("segmentation", (640, 480), None),  # the right size: past the checks, to the missing backbone
    ],
)
def test_cli_refuses_images_of_other_sizes_before_the_model(images, tmp_path, capsys, image, size, message):
    path = tmp_path / f"{image}.png"
    cv2.imwrite(str(path), np.zeros(size[::-1], np.uint16 if image == "depth" else np.uint8))
    code, _, err = _cli(capsys, *_place(images, tmp_path, **{image: path}))
    assert code == 2
    if message is None:
        assert "/nonexistent/ocplace-backbone" in err, err
    else:
        assert err.startswith(f"ocplace place: error: {message}"), err


# --- results files ---------------------------------------------------------------------------


def _results(tmp_path, **body) -> Path:
    path = tmp_path / "results.json"
    path.write_text(
        json.dumps(
            {
                "schema": "ocplace.evaluation/1",
                "dataset": {"dir": str(tmp_path), "dataset_hash": "0" * 16, "manifest_hash": "0" * 64},
                "settings": {"subsets": ["seen"]},
                **body,
            }
        )
    )
    return path


def _entry(**changes) -> dict:
    """An evaluation entry of a results file, complete but for `changes`."""
    return {"key": "ours", "method": "ours", "label": "Ours", "fraction": 1.0, "run_dir": None, "subsets": {}} | changes


@pytest.mark.parametrize(
    "body, named",
    [
        ({}, "evaluations"),
        ({"evaluations": {"ours": 1}}, "evaluations"),
        ({"evaluations": [{"method": "ours"}]}, "evaluations\\[0\\]"),
        ({"evaluations": [], "dataset": {}}, "dataset"),
        ({"evaluations": [], "settings": {"subsets": "seen"}}, "settings"),
        ({"evaluations": [_entry(subsets=["seen"])]}, "evaluations\\[0\\]"),
        ({"evaluations": [_entry(subsets={"seen": "all"})]}, "evaluations\\[0\\]"),
        ({"evaluations": [_entry(subsets={"seen": {"aggregate": {}, "scenes": [1]}})]}, "evaluations\\[0\\]"),
        ({"evaluations": [_entry(run_dir=3)]}, "evaluations\\[0\\]"),
    ],
)
def test_results_without_evaluations_are_refused(tmp_path, capsys, body, named):
    path = _results(tmp_path, **body)
    with pytest.raises(ResultsError, match=f"not a complete evaluation: {named} missing or malformed"):
        read_results(path)  # what the notebook calls
    code, _, err = _cli(capsys, "figures", path, "--out", tmp_path / "figures")
    assert code == 2 and err.startswith(f"ocplace figures: error: {path} is not a complete evaluation")
    assert not (tmp_path / "figures").exists()
    code, _, err = _cli(capsys, "evaluate", "--rerun", path)
    assert code == 2 and err.startswith(f"ocplace evaluate: error: {path} is not a complete evaluation")


@pytest.mark.parametrize(
    "changes, problem",
    [
        ({"dir": "/data/da\x00ta"}, "dataset.dir (it holds a NUL byte)"),
        ({"dir_relative": "../" + "d/" * 3000}, "dataset.dir_relative (it is longer than the 4,095 bytes"),
        ({"dir": "/data/" + "x" * 300}, "dataset.dir (a name in it is longer than the 255 bytes"),
    ],
)
def test_results_naming_folders_that_cannot_exist_are_refused(tmp_path, capsys, changes, problem):
    """Issue 60: a NUL byte or an over-long path in a results file was a raw ValueError or OSError."""
    path = _results(tmp_path, evaluations=[])
    body = json.loads(path.read_text())
    body["dataset"] |= changes
    path.write_text(json.dumps(body))
    code, _, err = _cli(capsys, "figures", path, "--out", tmp_path / "figures")
    assert code == 2 and f"{path} names folders that cannot exist: {problem}" in err, err
    code, _, err = _cli(capsys, "evaluate", "--rerun", path)
    assert code == 2 and problem in err, err


def test_results_settings_of_another_version_are_refused():
    with pytest.raises(ResultsError, match="settings are not those of this ocplace's evaluations"):
        settings_of({"settings": {"subsets": ["seen"], "sampler": "grid"}})


def test_truncated_results_are_refused(tmp_path, capsys):
    path = _results(tmp_path, evaluations=[])
    path.write_text(path.read_text()[:40])
    code, _, err = _cli(capsys, "figures", path, "--out", tmp_path / "figures")
    assert code == 2 and "is missing or not JSON" in err


# --- configuration overrides -----------------------------------------------------------------

CANNOT_RUN = "experiment 'smoke' cannot run: "


@pytest.mark.parametrize(
    "override, message",
    [
        ("recipes.ours.stepz=1", "unknown key 'recipes.ours.stepz': valid keys under 'recipes.ours' are adapters.*, "),
        ("dataset.train_scenes=many", "--set dataset.train_scenes=many: expected an integer, got 'many'"),
        ("evaluation", "--set takes KEY=VALUE, got 'evaluation'"),
        ("evaluation.num_samples=-1", CANNOT_RUN + "evaluation.num_samples must be from 1 to 65,536, got -1"),
        (
            "recipes.ours.schedule.learning_rate=-1",
            "--set recipes.ours.schedule.learning_rate=-1: -1 is out of range: give a number from 0 to 10",
        ),
        (
            "recipes.ours.schedule.learning_rate=nan",
            "--set recipes.ours.schedule.learning_rate=nan: nan is not a finite number",
        ),
        (
            "recipes.cliport.schedule.learning_rate=inf",
            "--set recipes.cliport.schedule.learning_rate=inf: inf is not a",
        ),
        ("backbone.optim.learning_rate=0", CANNOT_RUN + "backbone.optim.learning_rate must be positive, got 0.0"),
        (
            "recipes.no_llm.schedule.warmup_steps=-5",
            "--set recipes.no_llm.schedule.warmup_steps=-5: -5 is out of range: give a number from 0 to 10,000,000",
        ),
        (
            "recipes.ours.schedule.steps=-1",
            "--set recipes.ours.schedule.steps=-1: -1 is out of range: give a number from 1 to 10,000,000",
        ),
        (
            "evaluation.fractions=0.5,2.0",
            CANNOT_RUN + "evaluation.fractions holds 2.0; a training-set fraction lies in (0, 1]",
        ),
        (
            "evaluation.subsets=seen,bogus",
            CANNOT_RUN + "evaluation.subsets must name each test subset at most once, some of seen",
        ),
        ("evaluation.subsets=", CANNOT_RUN + "evaluation.subsets must name each test subset at most once"),
        ("evaluation.subsets=seen,dev_seen", CANNOT_RUN + "evaluation.subsets must name each test subset at most"),
        (
            "evaluation.parser=bogus",
            CANNOT_RUN + "evaluation.parser 'bogus' is not a parser; choose one of offline, offline-snap",
        ),
        ("evaluation.seeds=0", CANNOT_RUN + "evaluation.seeds must be at least 1, got 0"),
        ("evaluation.seed_fractions=0.5", CANNOT_RUN + "evaluation.seed_fractions holds 0.5, which is not trained"),
        ("evaluation.methods=", CANNOT_RUN + "evaluation.methods names no method"),
        ("dataset.test_scenes=0", CANNOT_RUN + "dataset.test_scenes must be at least 1, got 0"),
        ("dataset.physical_scenes=-2", CANNOT_RUN + "dataset.physical_scenes must be none (all) or at least 0, got -2"),
        ("evaluation.methods=ours,ours", CANNOT_RUN + "evaluation.methods names ours twice; name each method once"),
        ("seed=9223372036854775808", CANNOT_RUN + "seed must be from 0 to 4,294,967,295 (what numpy and JAX seed"),
        ("dataset.seed=-1", CANNOT_RUN + "dataset.seed must be from 0 to 4,294,967,295"),
        ("backbone.optim.seed=4294967296", CANNOT_RUN + "backbone.optim.seed must be from 0 to 4,294,967,295"),
    ],
)
def test_reproduce_refuses_a_bad_override_before_any_work(tmp_path, capsys, monkeypatch, override, message):
    from ocplace.experiments import pipeline

    monkeypatch.setattr(pipeline, "run_pipeline", lambda *args, **kwargs: pytest.fail("the pipeline started"))
    code, _, err = _cli(capsys, "reproduce", "--experiment", "smoke", "--set", override, "--out", tmp_path / "out")
    assert code == 2 and err.startswith(f"ocplace reproduce: error: {message}"), err
    assert not (tmp_path / "out").exists()


def test_reproduce_checks_its_methods_and_output_before_any_work(tmp_path, capsys, monkeypatch):
    from ocplace.experiments import pipeline

    monkeypatch.setattr(pipeline, "open_executor", lambda *args: pytest.fail("the pipeline started"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    for options, message in [
        (("--set", "out=afile/x"), "cannot write afile/x: afile is a file, not a folder"),
        (("--set", "out="), "--set out=: expected a path, got ''"),
        (("--out", "afile"), "cannot write into afile: it is a file, not a folder"),
        (("--set", "evaluation.seed_methods=ours,bogus"), "evaluation.seed_methods names bogus, not registered"),
        (("--set", "evaluation.fraction_methods=nope"), "evaluation.fraction_methods names nope, not registered"),
    ]:
        code, _, err = _cli(capsys, "reproduce", "--experiment", "smoke", *options)
        assert code == 2 and err.startswith("ocplace reproduce: error: ") and message in err, err
    for out in ("dangling", "dangling/deeper"):
        for command in (["reproduce", "--experiment", "smoke"], ["figures", tmp_path / "missing.json"]):
            code, _, err = _cli(capsys, *command, "--out", out)
            assert code == 2 and f"dangling is a symlink to {tmp_path / 'nowhere'}, which does not exist" in err, err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["afile", "dangling"]


def test_train_refuses_a_flag_value_its_field_cannot_take(capsys):
    with pytest.raises(SystemExit) as caught:
        main(["train", "--features", "f", "--out", "run", "--steps", "many"])
    assert caught.value.code == 2
    assert "argument --steps: expected an integer, got 'many'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("--learning-rate", "-1", "argument --learning-rate/--lr: -1 is out of range: give a number from 0 to 10"),
        ("--lr", "nan", "argument --learning-rate/--lr: nan is not a finite number"),
        ("--warmup-steps", "-5", "argument --warmup-steps: -5 is out of range: give a number from 0 to 10,000,000"),
        ("--logit-scale", "0", "argument --logit-scale: 0 is out of range: give a number from 0.001 to 1000"),
    ],
)
def test_train_refuses_a_bad_setting_before_reading_features(tmp_path, capsys, option, value, message):
    code, _, err = _cli(capsys, "train", "--features", tmp_path / "missing", "--out", tmp_path / "run", option, value)
    assert code == 2 and message in err, err  # refused as the flag is read (issue 60)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("--num-samples", "0", "argument --num-samples: 0 is out of range: give a whole number from 1 to 65,536"),
        ("--chunk-size", "-3", "argument --chunk-size: -3 is out of range: give a whole number from 1 to 4,096"),
        ("--limit", "0", "argument --limit: 0 is out of range: give a whole number from 1 to 99,999"),
        ("--seed", "-1", "argument --seed: -1 is out of range: give a whole number from 0 to 4,294,967,295"),
        ("--num-samples", "200000000", "argument --num-samples: 200000000 is out of range: give a whole number from 1"),
    ],
)
def test_evaluate_refuses_a_bad_setting_before_any_work(tmp_path, capsys, monkeypatch, option, value, message):
    from ocplace import runtime

    monkeypatch.setattr(runtime, "open_executor", lambda *args: pytest.fail("the evaluation started"))
    out = tmp_path / "results.json"
    code, _, err = _cli(capsys, "evaluate", "--dataset", tmp_path, "--out", out, "--methods", "oracle", option, value)
    assert code == 2 and message in err, err  # refused as the flag is read (issue 60)
    assert not out.exists()


def test_evaluation_settings_are_checked_where_evaluations_start():
    from ocplace.errors import EvaluationError
    from ocplace.eval.harness import EvalSettings
    from ocplace.experiments.evaluation import evaluate_runs

    EvalSettings().validate()
    EvalSettings(limit=1, physical_scenes=None, subsets=("unseen_cat",)).validate()
    for bad, message in (
        (
            EvalSettings(subsets=("seen", "seen")),
            "subsets must name each test subset, dev split or subset of your catalogue at most once",
        ),
        (
            EvalSettings(subsets=()),
            "subsets must name each test subset, dev split or subset of your catalogue at most once",
        ),
        (EvalSettings(subsets=("train",)), "; got train"),
        (EvalSettings(physical_scenes=-1), "physical_scenes must be at least 0 (none: every scene), got -1"),
    ):
        with pytest.raises(EvaluationError, match=re.escape(message)):
            evaluate_runs({}, [], "unused", bad, executor=None)


# --- outputs ---------------------------------------------------------------------------------


def test_out_under_a_file_or_in_a_read_only_folder_fails_first(images, tmp_path, capsys, read_only_dir):
    a_file = tmp_path / "a-file.txt"
    a_file.write_text("not a folder")
    for out, message in (
        (a_file / "place.png", f"{a_file} is a file, not a folder"),
        (a_file / "deeper" / "place.png", f"{a_file} is a file, not a folder"),
        (read_only_dir / "new" / "place.png", f"{read_only_dir} is not writable"),
    ):
        # an otherwise bad input too: the output is checked before everything else
        code, _, err = _cli(capsys, *_place(images, tmp_path, out=out, instruction=""))
        assert code == 2 and err.startswith(f"ocplace place: error: cannot write {out}: {message}"), err
        code, _, err = _cli(capsys, "figures", tmp_path / "missing.json", "--out", out)
        assert code == 2 and err.startswith(f"ocplace figures: error: cannot write {out}: {message}"), err
    check_writable(tmp_path / "new" / "deeper" / "file.png")  # folders still to make are fine
    assert not (tmp_path / "new").exists()


def test_a_full_disk_is_a_typed_error_naming_the_file(tmp_path):
    target = tmp_path / "out" / "results.json"
    with pytest.raises(OutputError, match=f"cannot write {target}: the disk is full"), atomic_path(target) as tmp:
        tmp.write_text("{")
        raise OSError(errno.ENOSPC, "No space left on device")  # what a write to a full disk raises
    assert list(target.parent.iterdir()) == []  # neither the target nor the temporary file


# --- the backbone the adapters were trained with ---------------------------------------------


@pytest.fixture(scope="module")
def saved_cache(tmp_path_factory):
    """A cache with one saved (tiny) offline backbone, and adapters trained on it by fingerprint."""
    from ocplace.models import offline_backbone as ob
    from ocplace.models import offline_config
    from ocplace.models.adapters import AdapterConfig, init_adapters
    from ocplace.models.backbone import PromptConfig
    from ocplace.models.trained_adapters import save_adapters
    from ocplace.paths import WEIGHTS_FILE

    cache = tmp_path_factory.mktemp("cache")
    config = offline_config.smoke_config()
    directory = ob.save_backbone(
        cache / "backbones" / "offline-tiny",  # paths.backbones_cache() once OCPLACE_CACHE names `cache`
        config,
        ob.init_params(config, jax.random.key(7)),  # not tiny_backbone_spec's
        ob.FrozenTextTower.load(config.text_max_length).digest,
    )
    fingerprint = (directory / ob.FINGERPRINT_FILE).read_text().strip()
    runs = {}
    for name, recorded in (("matching", fingerprint), ("orphan", "0" * 64)):
        adapters = AdapterConfig(dim=config.embed_dim)
        runs[name] = tmp_path_factory.mktemp(name)
        save_adapters(
            runs[name] / WEIGHTS_FILE,
            init_adapters(adapters, jax.random.key(1)),
            adapters,
            10.0,
            backbone_fingerprint=recorded,
            prompt=PromptConfig(),
            features_key="test",
            steps=0,
            train_config_json="{}",
        )
    return cache, directory, runs


def test_place_finds_the_backbone_the_adapters_were_trained_with(saved_cache, images, tmp_path, capsys, monkeypatch):
    cache, _, runs = saved_cache
    monkeypatch.setenv("OCPLACE_CACHE", str(cache))
    code, out, err = _cli(capsys, *_place(images, tmp_path, backbone=None, adapters=runs["matching"], samples=64))
    assert code == 0 and "error" not in err and "mode:" in out and (tmp_path / "place.png").stat().st_size > 1000


def test_place_says_how_to_get_a_missing_or_mismatched_backbone(
    saved_cache, images, tmp_path, capsys, monkeypatch, tiny_backbone_spec
):
    cache, directory, runs = saved_cache
    monkeypatch.setenv("OCPLACE_CACHE", str(cache))
    code, _, err = _cli(capsys, *_place(images, tmp_path, backbone=None, adapters=runs["orphan"]))
    assert code == 2 and err.startswith(
        f"ocplace place: error: {runs['orphan']} was trained on "
        "the backbone with fingerprint 000000000000 (no spec recorded); no saved offline backbone in"
    )
    assert "--backbone SPEC" in err
    code, _, err = _cli(capsys, *_place(images, tmp_path, backbone=tiny_backbone_spec, adapters=runs["matching"]))
    assert code == 2 and "were trained on features of another backbone" in err
    assert f"pass `--backbone offline:{directory}`" in err
    code, _, err = _cli(capsys, *_place(images, tmp_path, adapters=tmp_path / "no-run"))
    assert code == 2 and "no trained adapters at" in err  # before the (missing) backbone


def test_a_full_disk_still_prints_the_placement(saved_cache, images, tmp_path, capsys, monkeypatch, full_disk):
    cache, _, runs = saved_cache
    monkeypatch.setenv("OCPLACE_CACHE", str(cache))
    out = full_disk / "place.png"
    code, printed, err = _cli(
        capsys, *_place(images, tmp_path, backbone=None, adapters=runs["matching"], samples=64, out=out)
    )
    assert code == 2 and "mode:" in printed and f"wrote {out}" not in printed
    assert err.startswith(f"ocplace place: error: cannot write {out}: the disk is full")
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]


@pytest.mark.parametrize(
    "override",
    ["evaluation.num_samples=-1", "recipes.ours.schedule.learning_rate=nan", "evaluation.methods=nope", "out="],
)
def test_a_bad_set_fails_before_jax_is_imported(override, tmp_path):
    """The experiment is built and checked from JAX-free modules, so a bad value fails at once (exit 2)."""
    argv = ["reproduce", "--experiment", "smoke", "--out", str(tmp_path / "out"), "--set", override]
    probe = (
        "import sys\n"
        "from ocplace.cli import main\n"
        f"code = main({argv!r})\n"
        "print(code, 'jax' in sys.modules, 'ocplace.experiments.pipeline' in sys.modules)\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.stdout.split() == ["2", "False", "False"], result.stdout + result.stderr
    assert "ocplace reproduce: error:" in result.stderr and not (tmp_path / "out").exists()


def test_registered_names_are_the_specs_names_without_importing_them():
    from ocplace.methods.registry import method_specs, registered_names

    assert registered_names() == tuple(method_specs())


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "--cpus", "-5"], "argument --cpus: -5 is out of range: give a whole number from 0 to 4,096"),
        (["featurize", "--chunk-scenes", "0"], "argument --chunk-scenes: 0 is out of range"),
        (["generate", "--seed", "-1"], "argument --seed: -1 is out of range"),
        (["place", "--samples", "0"], "argument --samples: 0 is out of range: give a whole number from 1 to 65,536"),
        (["place", "--held-footprint", "nan", "nan"], "argument --held-footprint: nan is not a finite number"),
        (
            ["evaluate", "--physical", "-5"],
            "argument --physical: -5 is out of range: give a whole number from 0 to 99,999 (or -1)",
        ),
        (["place", "--seed", "x"], "argument --seed: 'x' is not a whole number"),
        (["train", "--seed", "-1"], "argument --seed: -1 is out of range: give a whole number from 0 to 4,294,967,295"),
    ],
)
def test_out_of_range_flags_are_usage_errors(capsys, argv, message):
    """Issue 43, defect 13: these were accepted (and meant "all", printed "nan%", or aborted a worker in XLA)."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_place_refuses_own_image_flags_beside_a_dataset_scene(tmp_path, capsys):
    """Issue 43, defect 13: `--held-footprint` with `--dataset` was accepted and ignored."""
    command = ["place", "--dataset", tmp_path, "--id", "0", "--held-footprint", "0.2", "0.2"]
    code, _, err = _cli(capsys, *command)
    assert code == 2 and "--held-footprint describe your own images; a --dataset scene has its own" in err


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--chunk-steps", "0"], "argument --chunk-steps: 0 is out of range: give a number from 1 to 100,000"),
        (["--reduction", "0"], "argument --reduction: 0 is out of range: give a number from 1 to 8,192"),
        (["--subset-seed", "-1"], "argument --subset-seed: -1 is out of range: give a number from 0 to 4,294,967,295"),
        (["--fraction", "1.5"], "argument --fraction: 1.5 is out of range: give a number from 0.001 to 1"),
    ],
)
def test_train_refuses_settings_that_cannot_train(tmp_path, capsys, flags, message):
    code, _, err = _cli(capsys, "train", "--features", tmp_path / "none.safetensors", "--out", tmp_path / "run", *flags)
    assert code == 2 and message in err and not (tmp_path / "run").exists()
