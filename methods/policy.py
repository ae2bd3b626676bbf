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
import importlib
import inspect
import signal
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ocplace.errors import EvaluationError
from ocplace.eval.api import Method, MethodOutput
from ocplace.eval.harness import POLICY_ERRORS, EvalSettings, evaluate_run, physical_arena
from ocplace.methods.api import LoadContext, MethodSpec
from ocplace.methods.registry import method_run
from ocplace.sim.dataset.records import SceneRecord
from ocplace.vocabulary import SCENE_TIMEOUT_S

REFERENCE_HELP = (
    "a policy is named MODULE:CALLABLE, e.g. my_policies:place or my_pkg.policies:MyPolicy; the module must be "
    "importable (the command adds the current folder to the import path; else set PYTHONPATH)"
)


def is_policy_name(name: str) -> bool:
    """Whether a method name is a policy's `MODULE:CALLABLE` reference, not a registered method's."""
    return ":" in name


def import_policy(reference: str):
    """The object `MODULE:ATTRIBUTE[.ATTRIBUTE...]` names; EvaluationError when it cannot be imported."""
    module_name, _, attributes = reference.partition(":")
    if not module_name or not attributes:
        raise EvaluationError(f"cannot read the policy reference {reference!r}: {REFERENCE_HELP}")
    if module_name == "__main__" or any(part.startswith("<") for part in attributes.split(".")):
        where = (
            "in a script run directly (__main__)" if module_name == "__main__" else "inside a function, or as a lambda"
        )
        raise EvaluationError(
            f"the policy {reference!r} was defined {where}, so no other process can import it again: "
            "put it in a module (a .py file in the current folder will do) and name it MODULE:CALLABLE"
        )
    try:
        target = importlib.import_module(module_name)
    except ImportError as error:
        raise EvaluationError(f"cannot import the policy module {module_name!r} ({error}); {REFERENCE_HELP}") from None
    except POLICY_ERRORS as error:  # a SyntaxError, or anything its own code raises while it is imported
        raise EvaluationError(
            f"the policy module {module_name!r} failed while it was imported ({type(error).__name__}: {error}); "
            "fix it, or import it yourself to see the traceback"
        ) from None
    for attribute in attributes.split("."):
        if not hasattr(target, attribute):
            raise EvaluationError(f"{module_name} has no {attributes!r} for the policy {reference!r}; {REFERENCE_HELP}")
        target = getattr(target, attribute)
    if not (callable(target) or _is_method(target) or callable(getattr(target, "place", None))):
        raise EvaluationError(
            f"{reference} is a {type(target).__name__}: a policy is a Method (describe and run), a callable "
            "place(observation) -> (x, y), an object with such a place method, or a class making one"
        )
    return target


class SceneTimeout(TimeoutError):
    """A policy past its time on a scene (`--scene-timeout`): that scene fails, the evaluation goes on."""


@contextlib.contextmanager
def deadline(seconds: float):
    """Raises `SceneTimeout` in this thread once `seconds` have passed, and again every second until the block
    ends (a policy that swallows the first does not hang the evaluation). A signal timer: only in the main thread
    (elsewhere, and for `seconds <= 0`, no deadline), and a call stuck in native code is interrupted only when
    it returns to Python."""
    if seconds <= 0 or threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum, frame):
        raise SceneTimeout(f"timeout: the policy took more than {seconds:g} s (--scene-timeout)")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds, 1.0)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _is_method(policy) -> bool:
    return callable(getattr(policy, "run", None)) and callable(getattr(policy, "describe", None))


@dataclasses.dataclass
class PlacerMethod:
    """A `Method` around `place(observation) -> (x, y)`: one call per scene, in the harness's scene order."""

    name: str
    place: Callable
    scene_timeout_s: float = SCENE_TIMEOUT_S

    def describe(self) -> dict:
        return {"policy": self.name, "interface": "place(observation) -> (x, y)"}

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        from ocplace.sim.env.observation import observation

        outputs = []
        for scene in scenes:
            # Caught here, not by the harness: it would run the whole chunk again scene by scene, so a
            # stateful placer (one random generator for all scenes) would see other calls than in the env.
            try:
                with deadline(self.scene_timeout_s):
                    mode = self.place(observation(scene))
            except POLICY_ERRORS as error:
                outputs.append(MethodOutput(mode=None, samples=None, failure=f"{type(error).__name__}: {error}"))
            else:  # the harness checks the shape and finiteness: anything else is a failure there
                outputs.append(MethodOutput(mode=mode, samples=None))
        return outputs


@dataclasses.dataclass
class TimedMethod:
    """A policy's own `Method`, under a deadline of `scene_timeout_s` per scene of each call (the harness then
    runs a chunk past it again scene by scene, so only the slow scene fails)."""

    method: Method
    scene_timeout_s: float = SCENE_TIMEOUT_S

    def describe(self) -> dict:
        return self.method.describe()

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        with deadline(self.scene_timeout_s * len(scenes)):
            return self.method.run(scenes, key)


def as_method(policy, name: str, scene_timeout_s: float = SCENE_TIMEOUT_S) -> Method:
    """The `Method` that runs `policy` (a Method, a placer, an object with a `place` method, or a class), each
    scene under a deadline of `scene_timeout_s` (0: none)."""
    if inspect.isclass(policy):
        try:
            policy = policy()
        except POLICY_ERRORS as error:
            raise EvaluationError(
                f"the policy class {name!r} failed when made with no arguments ({type(error).__name__}: {error})"
            ) from None
    if _is_method(policy):
        return TimedMethod(policy, scene_timeout_s)
    place = getattr(policy, "place", policy)
    if not callable(place):
        raise EvaluationError(f"policy {name!r} is neither a Method (describe and run) nor a placer (place)")
    return PlacerMethod(name, place, scene_timeout_s)


def load_policy(reference: str, context: LoadContext | None = None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> Method:
    """`MethodSpec.load` of a policy: imports it anew (in an evaluation's worker process)."""
    return as_method(import_policy(reference), reference, scene_timeout_s)


def policy_spec(reference: str, label: str | None = None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> MethodSpec:
    """The spec of the policy `MODULE:CALLABLE`, imported here so that a bad reference fails before any work.

    Its Table I label: `label`, else the policy's `label` attribute, else the reference.
    """
    return _spec(import_policy(reference), reference, label, scene_timeout_s)


def _spec(policy, name: str, label: str | None, scene_timeout_s: float = SCENE_TIMEOUT_S) -> MethodSpec:
    label = label or getattr(policy, "label", None) or name
    load = functools.partial(load_policy, name, scene_timeout_s=scene_timeout_s)
    return MethodSpec(name=name, label=label, load=load)


def with_policies(
    specs: Mapping[str, MethodSpec],
    results: Mapping,
    trusted: set[str] = frozenset(),
    trust_all: bool = False,
    scene_timeout_s: float = SCENE_TIMEOUT_S,
) -> dict[str, MethodSpec]:
    """`specs` plus a spec for each policy a results file evaluated (method names `MODULE:CALLABLE`).

    No module is imported because a file names it: only the policies the user names again (`trusted`, the
    command's `--policy`), or all with `trust_all` (`--trust-policy`); any other is an EvaluationError saying so.
    """
    named = [e["method"] for e in results["evaluations"] if is_policy_name(e["method"]) and e["method"] not in specs]
    untrusted = [name for name in named if name not in trusted and not trust_all]
    if untrusted:
        raise EvaluationError(
            f"the results file names the policies {', '.join(map(repr, untrusted))}; a results file never makes "
            "ocplace import code: name each again with --policy MODULE:CALLABLE (or pass --trust-policy) to rerun it"
        )
    labels = {e["method"]: e["label"] for e in results["evaluations"]}
    return dict(specs) | {name: policy_spec(name, labels[name], scene_timeout_s) for name in named}


def reference_of(policy) -> str:
    """`MODULE:QUALNAME` of a function or class, or of an object's class."""
    named = policy if inspect.isclass(policy) or inspect.isroutine(policy) else type(policy)
    return f"{named.__module__}:{named.__qualname__}"


def evaluate_policy(
    policy,
    dataset_dir: str | Path,
    settings: EvalSettings = EvalSettings(),
    *,
    label: str | None = None,
    progress: bool = False,
    scene_timeout_s: float = SCENE_TIMEOUT_S,
) -> dict:
    """Scores `policy` on the test subsets of `dataset_dir` with the harness, in this process.

    `policy` is a `MODULE:CALLABLE` reference or the policy itself (a Method, a placer, an object
    with a `place` method, or a class). Returns the results (`ocplace.evaluation/1`, docs/evaluation.md):
    `ocplace.eval.table.render(results)` gives Table I and the other tables,
    `ocplace.eval.results.write_outputs(results, path)` writes them and the JSON.
    """
    from ocplace.eval.results import build_results

    name, policy = (policy, import_policy(policy)) if isinstance(policy, str) else (reference_of(policy), policy)
    spec, method = _spec(policy, name, label, scene_timeout_s), as_method(policy, name, scene_timeout_s)
    with physical_arena(settings) as arena:
        evaluation = evaluate_run(method_run(spec), method, dataset_dir, settings, arena, progress=progress)
    command = {"python": "ocplace.methods.policy.evaluate_policy", "policy": spec.name}
    return build_results([evaluation], dataset_dir, settings, command)
