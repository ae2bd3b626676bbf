"""Any policy on the benchmark: `ocplace evaluate --policy MODULE:CALLABLE` and `evaluate_policy`.

A policy is one of
- a `Method` (eval/api.py: `describe()` and `run(scenes, key) -> [MethodOutput]`), run as the
  registered methods are;
- a placer: a callable `place(observation) -> (x, y)`, or an object with such a `place` method. It
  gets each scene as the Gymnasium environment's observation (`ocplace.sim.env.observation`) and
  returns the held object's table-frame placement in metres.
A class is instantiated with no arguments first. The harness scores a policy as any method: same
scenes, metric, physical check and tables; its Table I row carries the policy's label. The method
name of a policy is its `MODULE:CALLABLE` reference (registered names have no colon), which is how
`ocplace evaluate --rerun --policy MODULE:CALLABLE` imports it again (never a results file alone).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib.util
import inspect
import signal
import threading
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import numpy as np

from ocplace.errors import POLICY_ERRORS, EvaluationError, PolicyProcessEnded, PolicyRaised, SceneTimeout
from ocplace.eval.api import Method, MethodOutput
from ocplace.eval.harness import EvalSettings, evaluate_run, physical_arena
from ocplace.methods.contract import LoadContext, MethodSpec
from ocplace.methods.folder_method import folder_spec, is_folder_reference
from ocplace.methods.policy_host import (
    PolicyHost,
    describe_error,
    import_policy,
    is_method,
    is_policy_name,
    made,
    placement_numbers,
)
from ocplace.methods.registry import method_run
from ocplace.sim.dataset.records import SceneRecord
from ocplace.vocabulary import SCENE_TIMEOUT_S

if TYPE_CHECKING:
    import jax

__all__ = ["evaluate_policy", "import_policy", "is_policy_name", "policy_spec", "with_policies"]


@contextlib.contextmanager
def deadline(seconds: float) -> Iterator[None]:
    """Raises `SceneTimeout` in this thread once `seconds` have passed, and again every second until the block
    ends (a policy that swallows the first does not hang the evaluation). For a policy given as an object, which
    runs in this process: a signal timer, only in the main thread (elsewhere, and for `seconds <= 0`, no
    deadline); a call stuck in native code is interrupted only when it returns to Python. A policy named
    `MODULE:CALLABLE` runs in its own process instead (`HostedPolicy`), killed at its deadline."""
    if seconds <= 0 or threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum: int, frame: FrameType | None) -> None:
        raise SceneTimeout(f"timeout: the policy took more than {seconds:g} s (--scene-timeout)")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds, 1.0)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _placer_failure(error: BaseException) -> MethodOutput:
    return MethodOutput(mode=None, samples=None, failure=describe_error(error))


PLACER_DESCRIPTION = "place(observation) -> (x, y)"


def placer_description(reference: str, scene_timeout_s: float) -> dict[str, Any]:
    """A placer's `describe()`: its name, deadline and the sha256 of its module's file, so that a stored
    evaluation (a resumed `evaluate`) or a `--rerun` sees an edited policy as another one."""
    return {
        "policy": reference,
        "interface": PLACER_DESCRIPTION,
        "scene_timeout_s": scene_timeout_s,
        "module_sha256": module_sha256(reference.partition(":")[0]),
    }


def module_sha256(module_name: str) -> str | None:
    """sha256 of the file a module is imported from (None: no file, such as a built-in or `__main__` module)."""
    try:
        spec = importlib.util.find_spec(module_name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin or not Path(spec.origin).is_file():
        return None
    return hashlib.sha256(Path(spec.origin).read_bytes()).hexdigest()


@dataclasses.dataclass
class PlacerMethod:
    """A `Method` around `place(observation) -> (x, y)` given as an object: one call per scene, in this process,
    in the harness's scene order."""

    name: str
    place: Callable[..., Any]
    scene_timeout_s: float = SCENE_TIMEOUT_S

    def describe(self) -> dict[str, Any]:
        return placer_description(self.name, self.scene_timeout_s)

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        from ocplace.sim.env.observation import observation

        outputs = []
        for scene in scenes:
            # Caught here, not by the harness: it would run the whole chunk again scene by scene, so a
            # stateful placer (one random generator for all scenes) would see other calls than in the env.
            try:
                with deadline(self.scene_timeout_s):
                    mode = placement_numbers(self.place(observation(scene)))
            except POLICY_ERRORS as error:
                outputs.append(_placer_failure(error))
            else:  # the harness checks the shape and finiteness: anything else is a failure there
                outputs.append(MethodOutput(mode=np.asarray(mode, np.float64), samples=None))
        return outputs


@dataclasses.dataclass
class TimedMethod:
    """A policy's own `Method` given as an object, under a deadline of `scene_timeout_s` per scene of each call
    (the harness then runs a chunk past it again scene by scene, so only the slow scene fails)."""

    method: Method
    scene_timeout_s: float = SCENE_TIMEOUT_S

    @property
    def name(self) -> str:
        return self.method.name

    def describe(self) -> dict[str, Any]:
        return self.method.describe()

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        with deadline(self.scene_timeout_s * len(scenes)):
            return self.method.run(scenes, key)


class HostedPolicy:
    """A policy named `MODULE:CALLABLE`, run in its own process (`methods/policy_host.py`): past its deadline, or
    when that process dies, the scene fails and a fresh process takes the next one."""

    def __init__(self, reference: str, scene_timeout_s: float = SCENE_TIMEOUT_S, jax_width: int | None = None):
        self.name = reference
        self.scene_timeout_s = scene_timeout_s
        self.host = PolicyHost(reference, jax_width)

    def describe(self) -> dict[str, Any]:
        if self.host.ready["kind"] == "method":
            described: dict[str, Any] = self.host.ready["describe"]
            return described
        return placer_description(self.name, self.scene_timeout_s)

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        if self.host.ready["kind"] == "method":
            return self._run_method(scenes, key)
        from ocplace.sim.env.observation import observation

        outputs = []
        for scene in scenes:
            try:
                answer = self.host.request(("place", observation(scene)), self.scene_timeout_s)
            except (SceneTimeout, PolicyProcessEnded, EvaluationError) as error:
                outputs.append(_placer_failure(error))
                continue
            if "error" in answer:
                outputs.append(MethodOutput(mode=None, samples=None, failure=answer["error"]))
            else:
                outputs.append(MethodOutput(mode=np.asarray(answer["mode"], np.float64), samples=None))
        return outputs

    def _run_method(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        """The policy's `run` in its process; whatever goes wrong is raised, so that the harness runs the chunk
        again scene by scene and only the scene at fault fails."""
        import jax

        request = ("run", list(scenes), np.asarray(jax.random.key_data(key)))
        answer = self.host.request(request, self.scene_timeout_s * len(scenes))
        if "error" in answer:
            raise PolicyRaised(answer["error"])
        # An output the policy's process could not describe holds only its failure ("malformed output: ...").
        return [MethodOutput(**({"mode": None, "samples": None} | output)) for output in answer["outputs"]]


def as_method(policy: object, name: str, scene_timeout_s: float = SCENE_TIMEOUT_S) -> Method:
    """The `Method` that runs `policy` (a Method, a placer, an object with a `place` method, or a class) in this
    process, each scene under a deadline of `scene_timeout_s` (0: none)."""
    policy = made(policy, name)
    if is_method(policy):
        return TimedMethod(policy, scene_timeout_s)
    place = getattr(policy, "place", policy)
    if not callable(place):
        raise EvaluationError(f"policy {name!r} is neither a Method (describe and run) nor a placer (place)")
    return PlacerMethod(name, place, scene_timeout_s)


def load_policy(reference: str, context: LoadContext | None = None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> Method:
    """`MethodSpec.load` of a policy: started anew in a process of its own (from an evaluation's worker, whose
    tasks run JAX one CPU wide: so does the policy's process)."""
    return HostedPolicy(reference, scene_timeout_s, jax_width=1)


def policy_spec(reference: str, label: str | None = None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> MethodSpec[Any]:
    """The spec of the policy `MODULE:CALLABLE`, imported here so that a bad reference fails before any work.

    Its Table I label: `label`, else the policy's `label` attribute, else the reference. A policy folder
    (`ocplace export`; `methods/folder_method.py`) is a spec too, and imports nothing.
    """
    if is_folder_reference(reference):
        return folder_spec(reference, label)
    return _spec(import_policy(reference), reference, label, scene_timeout_s)


def _spec(policy: object, name: str, label: str | None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> MethodSpec[Any]:
    label = label or getattr(policy, "label", None) or name
    load = functools.partial(load_policy, name, scene_timeout_s=scene_timeout_s)
    return MethodSpec(name=name, label=label, load=load)


def with_policies(
    specs: Mapping[str, MethodSpec[Any]],
    results: Mapping[str, Any],
    trusted: Collection[str] = frozenset(),
    trust_all: bool = False,
    scene_timeout_s: float = SCENE_TIMEOUT_S,
) -> dict[str, MethodSpec[Any]]:
    """`specs` plus a spec for each policy a results file evaluated (method names `MODULE:CALLABLE`).

    No module is imported because a file names it: only the policies the user names again (`trusted`, the
    command's `--policy`), or all with `trust_all` (`--trust-policy`); any other is an EvaluationError saying so.
    """
    named = [e["method"] for e in results["evaluations"] if is_policy_name(e["method"]) and e["method"] not in specs]
    untrusted = [name for name in named if name not in trusted and not trust_all and not is_folder_reference(name)]
    if untrusted:
        raise EvaluationError(
            f"the results file names the policies {', '.join(map(repr, untrusted))}; a results file never makes "
            "ocplace import code: name each again with --policy MODULE:CALLABLE (or pass --trust-policy) to rerun it"
        )
    labels = {e["method"]: e["label"] for e in results["evaluations"]}
    return dict(specs) | {name: policy_spec(name, labels[name], scene_timeout_s) for name in named}


def reference_of(policy: object) -> str:
    """`MODULE:QUALNAME` of a function or class, or of an object's class."""
    named = policy if inspect.isclass(policy) or inspect.isroutine(policy) else type(policy)
    return f"{named.__module__}:{named.__qualname__}"


def evaluate_policy(
    policy: object,
    dataset_dir: str | Path,
    settings: EvalSettings = EvalSettings(),
    *,
    label: str | None = None,
    progress: bool = False,
    scene_timeout_s: float = SCENE_TIMEOUT_S,
) -> dict[str, Any]:
    """Scores `policy` on the test subsets of `dataset_dir` with the harness.

    `policy` is a `MODULE:CALLABLE` reference, run in a process of its own (killed at its deadline), or the
    policy itself (a Method, a placer, an object with a `place` method, or a class), run in this process.
    Returns the results (`ocplace.evaluation/1`, docs/evaluation.md):
    `ocplace.eval.table.render(results)` gives Table I and the other tables,
    `ocplace.eval.table.write_outputs(results, path)` writes them and the JSON.
    """
    from ocplace.eval.results import build_results

    method: Method
    if isinstance(policy, str):
        name = policy
        spec, method = _spec(import_policy(name), name, label, scene_timeout_s), HostedPolicy(name, scene_timeout_s)
    else:
        name = reference_of(policy)
        spec, method = _spec(policy, name, label, scene_timeout_s), as_method(policy, name, scene_timeout_s)
    with physical_arena(settings, dataset_dir) as arena:
        evaluation = evaluate_run(method_run(spec), method, dataset_dir, settings, arena, progress=progress)
    command = {"python": "ocplace.methods.external_policy.evaluate_policy", "policy": spec.name}
    return build_results([evaluation], dataset_dir, settings, command)
