"""A policy named `MODULE:CALLABLE` in a process of its own, so that its deadline holds even in native code.

The evaluation sends each request (an observation for a placer, redacted scenes and a key for a `Method`)
to the policy's process and waits at most its deadline. Past it, or when that process ended (a crash,
`os._exit`, a signal), the process is killed, the scene is a failure and the next request starts a fresh
process (a stateful policy starts from its constructor again). Requests go down pickled (the evaluation
made them); answers come back as JSON only, so nothing the policy returns is unpickled here.

This module imports little at its top: a placer's process loads only it, numpy and the policy.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import json
import multiprocessing
import os
import signal
import threading
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np

from ocplace.errors import POLICY_ERRORS, EvaluationError, PolicyProcessEnded, SceneTimeout
from ocplace.paths import MAX_JSON_DEPTH, json_depth, processes_cache
from ocplace.runtime.processes import (
    become_subreaper,
    forget_process,
    kill_tree,
    reap_leftovers,
    record_process,
)

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess

    from ocplace.eval.api import Method

    Pipe = Connection[Any, Any]

LOAD_TIMEOUT_S = 600.0  # importing and constructing the policy; a scene's deadline starts after it
SEND_TIMEOUT_S = 120.0  # handing a request to a policy's process when its scenes have no deadline (a frozen one)
# The largest answer read: a placement is a few bytes; a Method's output per scene at most MAX_SAMPLES samples.
ANSWER_BYTES_PER_SCENE = 4 << 20
ANSWER_KEYS = {"place": ("mode", "error"), "run": ("outputs", "error"), "ready": ("kind", "describe", "error")}
OUTPUT_KEYS = frozenset(("mode", "samples", "parsed", "grounded", "failure", "parse_note", "confidence"))

REFERENCE_HELP = (
    "a policy is named MODULE:CALLABLE, e.g. my_policies:place or my_pkg.policies:MyPolicy; the module must be "
    "importable (the command adds the current folder to the import path; else set PYTHONPATH)"
)


def is_policy_name(name: str) -> bool:
    """Whether a method name is a policy's `MODULE:CALLABLE` reference, not a registered method's."""
    return ":" in name


def import_policy(reference: str) -> object:
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
        target: object = importlib.import_module(module_name)
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
    if not (callable(target) or is_method(target) or callable(getattr(target, "place", None))):
        raise EvaluationError(
            f"{reference} is a {type(target).__name__}: a policy is a Method (describe and run), a callable "
            "place(observation) -> (x, y), an object with such a place method, or a class making one"
        )
    return target


def is_method(policy: object) -> TypeGuard[Method]:
    return callable(getattr(policy, "run", None)) and callable(getattr(policy, "describe", None))


def made(policy: object, name: str) -> object:
    """`policy`, or the object its class makes with no arguments (EvaluationError when that fails)."""
    if not inspect.isclass(policy):
        return policy
    try:
        return policy()
    except POLICY_ERRORS as error:
        raise EvaluationError(
            f"the policy class {name!r} failed when made with no arguments ({type(error).__name__}: {error})"
        ) from None


def placement_numbers(mode: object) -> list[Any]:
    """A placer's answer as nested float lists (the harness checks the shape); strings, booleans and objects
    are no placements, as in the environment (`"0.1"` would convert)."""
    kind = np.asarray(mode).dtype.kind
    if kind in "USb":
        raise TypeError(f"a placement is numbers, not {np.asarray(mode).dtype} ({type(mode).__name__})")
    numbers: list[Any] = np.asarray(mode, dtype=np.float64).tolist()
    return numbers


def describe_error(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


# ----------------------------------------------------------------------------- the policy's process


def serve(reference: str, connection: Pipe, jax_width: int | None = None) -> None:
    """The policy's process: loads it, says what it is, then answers requests until the pipe closes.

    With `jax_width`, the process is pinned to that many CPUs while the policy is imported, made and answers its
    first request: JAX, should the policy start it then, sizes itself to them as in the evaluation's worker (the
    same bits anywhere), and a placer that never runs JAX pays nothing for it."""
    from ocplace.runtime.executor import exit_with_parent
    from ocplace.runtime.width import pinned_cpus

    os.setpgid(0, 0)  # a group of its own: what the policy starts is killed with it (`_stop`)
    become_subreaper()  # and what it starts through a child that ended is still below it
    exit_with_parent(lambda: kill_tree(os.getpid()))
    # The kernel's word that the command died while this process was stopped (its group orphaned): SIGHUP, then
    # SIGCONT. By default SIGHUP would end this process alone, orphaning what it started in sessions of their own.
    signal.signal(signal.SIGHUP, lambda *_: kill_tree(os.getpid()))
    with pinned_cpus(jax_width) if jax_width else contextlib.nullcontext():
        policy = _loaded(reference, connection)
        if policy is None or not _answered(policy, connection):
            return
    while _answered(policy, connection):
        pass


def _loaded(reference: str, connection: Pipe) -> Any:
    """The policy, ready to answer, after telling the evaluation what it is; None (and why, sent) when it fails."""
    try:
        policy = made(import_policy(reference), reference)
        ready = _ready(policy)
    except EvaluationError as error:
        connection.send_bytes(json.dumps({"error": str(error)}).encode())
        return None
    connection.send_bytes(json.dumps(ready).encode())
    return getattr(policy, "place", policy) if ready["kind"] == "placer" else policy


def _answered(policy: Any, connection: Pipe) -> bool:
    """Answers the next request; False once the pipe is closed."""
    try:
        request = connection.recv()
    except EOFError:
        return False
    connection.send_bytes(json.dumps(_answer(policy, request)).encode())
    return True


def _ready(policy: object) -> dict[str, Any]:
    """What the policy is (and a `Method`'s description), JSON; EvaluationError when its `describe` fails."""
    if not is_method(policy):
        return {"kind": "placer"}
    from ocplace import serial

    try:
        return {"kind": "method", "describe": json.loads(json.dumps(serial.to_dict(policy.describe())))}
    except POLICY_ERRORS as error:
        raise EvaluationError(f"the policy's describe() failed ({describe_error(error)})") from None


def _answer(policy: Any, request: tuple[Any, ...]) -> dict[str, Any]:
    try:
        if request[0] == "place":
            return {"mode": placement_numbers(policy(request[1]))}
        import jax
        import jax.numpy as jnp

        scenes, key_data = request[1], request[2]
        outputs = policy.run(scenes, jax.random.wrap_key_data(jnp.asarray(key_data, jnp.uint32)))
        return {"outputs": [_output_json(output) for output in outputs]}
    except POLICY_ERRORS as error:
        return {"error": describe_error(error)}


def _output_json(output: object) -> dict[str, Any]:
    """A `MethodOutput` as JSON (numbers as lists; the harness checks them as it checks any method's)."""
    from ocplace.eval.api import MethodOutput

    if not isinstance(output, MethodOutput):
        return {"failure": f"malformed output: {type(output).__name__}, not a MethodOutput"}
    try:

        def numbers(value: object) -> Any:
            return None if value is None else np.asarray(value, dtype=np.float64).tolist()

        return {
            "mode": numbers(output.mode),
            "samples": numbers(output.samples),
            "parsed": None if output.parsed is None else [[str(r), str(rel)] for r, rel in output.parsed],
            "grounded": None if output.grounded is None else [int(t) for t in output.grounded],
            "failure": None if output.failure is None else str(output.failure),
            "parse_note": output.parse_note if isinstance(output.parse_note, str) else None,
            "confidence": None if output.confidence is None else float(output.confidence),
        }
    except POLICY_ERRORS as error:
        return {"failure": output.failure or f"malformed output: {describe_error(error)}"}


# ----------------------------------------------------------------------------- the evaluation's side


def _stop(process: BaseProcess, connection: Pipe, note: Path | None) -> int | None:
    """Kills `process` (if running) and all it started, and frees its pipe, handles and `note`; its exit code."""
    if process.pid is not None:
        kill_tree(process.pid)
    forget_process(note)
    if process.is_alive():
        process.kill()
    process.join()
    connection.close()
    code = process.exitcode
    process.close()
    return code


def _answer_problem(answer: object, kind: str) -> str | None:
    """What keeps a decoded answer from being one of `kind` ("place", "run", "ready"); None when it is one."""
    if not isinstance(answer, dict) or not answer or set(answer) - set(ANSWER_KEYS[kind]):
        return f"an object with {' or '.join(ANSWER_KEYS[kind])} is needed"
    if "error" in answer and not isinstance(answer["error"], str):
        return "its error is not a text"
    if kind == "run" and "outputs" in answer:
        outputs = answer["outputs"]
        if not isinstance(outputs, list) or not all(isinstance(o, dict) and set(o) <= OUTPUT_KEYS for o in outputs):
            return f"its outputs are not a list of objects with some of {', '.join(sorted(OUTPUT_KEYS))}"
    if kind == "ready" and answer.get("kind") not in ("placer", "method", None):
        return "its kind is neither placer nor method"
    return None


def _short(data: bytes) -> str:
    text = data[:60].decode("utf-8", "replace")
    return repr(text + ("..." if len(data) > 60 else ""))


class PolicyHost:
    """The evaluation's handle on the policy's process, started on the first request and again after a kill.

    The process is not a daemon, so that a policy may start processes of its own; it ends when its pipe closes,
    when this handle is collected or the interpreter exits (`weakref.finalize`), or within a second of its
    parent's end (`exit_with_parent`)."""

    def __init__(self, reference: str, jax_width: int | None = None):
        self.reference, self.jax_width = reference, jax_width
        self._process: BaseProcess | None = None
        self._connection: Pipe | None = None
        self._finalizer: weakref.finalize[[BaseProcess, Pipe, Path | None], PolicyHost] | None = None
        self.ready: dict[str, Any] = self._start()

    def _start(self) -> dict[str, Any]:
        notes = processes_cache()
        reap_leftovers(notes)  # what an earlier command killed with SIGKILL left: nothing of it could end them
        context = multiprocessing.get_context("spawn")  # never fork a process that runs JAX or EGL
        connection, child_end = context.Pipe()
        arguments = (self.reference, child_end, self.jax_width)
        process = context.Process(target=serve, args=arguments, daemon=False, name="ocplace-policy")
        process.start()
        child_end.close()
        self._process, self._connection = process, connection
        note = record_process(notes, process.pid) if process.pid is not None else None
        self._finalizer = weakref.finalize(self, _stop, process, connection, note)
        ready = self._receive(LOAD_TIMEOUT_S, loading=True)
        if "error" in ready:
            self.stop()
            raise EvaluationError(ready["error"])
        return ready

    def request(self, request: tuple[Any, ...], timeout_s: float) -> dict[str, Any]:
        """The policy's JSON answer to `request` within `timeout_s` (0: no deadline but SEND_TIMEOUT_S to take it);
        SceneTimeout, or PolicyProcessEnded when its process ended or answered something that is not an answer of
        at most its size: its process (and what it started) is then killed, and the next request starts another."""
        if self._process is None:
            self._start()
        size = ANSWER_BYTES_PER_SCENE * (len(request[1]) if request[0] == "run" else 1)
        return self._exchange(request, timeout_s if timeout_s > 0 else None, request[0], size)

    def _receive(self, timeout_s: float | None, loading: bool = False) -> dict[str, Any]:
        return self._exchange(None, timeout_s, "ready", ANSWER_BYTES_PER_SCENE, loading)

    def _exchange(
        self, request: tuple[Any, ...] | None, timeout_s: float | None, kind: str, size: int, loading: bool = False
    ) -> dict[str, Any]:
        """Sends `request` (None: nothing) and reads the answer in a thread of its own, so that a policy that stops
        reading, or announces an answer and never sends it, costs the deadline and no more."""
        assert self._connection is not None, "called on a started process"
        connection, got = self._connection, dict[str, Any]()

        def talk() -> None:
            try:
                if request is not None:
                    connection.send(request)
                got["sent"] = True
                if connection.poll(timeout_s):
                    got["data"] = connection.recv_bytes(size)
            except (EOFError, OSError) as error:  # it ended, or announced more than `size` bytes
                got["error"] = error

        thread = threading.Thread(target=talk, name="ocplace-policy-exchange", daemon=True)
        thread.start()
        thread.join(None if timeout_s is None and request is None else (timeout_s or SEND_TIMEOUT_S))
        if thread.is_alive() and timeout_s is None and got.get("sent"):
            thread.join()  # sent; the scenes have no deadline
        if thread.is_alive() or ("data" not in got and "error" not in got):
            self.stop()
            thread.join()
            what = "to load" if loading else "(--scene-timeout)" if got.get("sent") else "to take the request"
            raise SceneTimeout(f"timeout: the policy took more than {timeout_s or SEND_TIMEOUT_S:g} s {what}")
        if "error" in got:
            code = self.stop()
            if str(got["error"]) == "bad message length":  # multiprocessing read the frame's header only
                raise PolicyProcessEnded(
                    f"the policy's process announced an answer past {size:,} bytes: it was stopped"
                )
            when = " while it was loaded" if loading else ""
            raise PolicyProcessEnded(f"the policy's process ended{when} (exit code {code})") from None
        return self._decoded(got["data"], kind)

    def _decoded(self, data: bytes, kind: str) -> dict[str, Any]:
        try:
            answer = json.loads(data)
            problem = _answer_problem(answer, kind) if json_depth(answer) <= MAX_JSON_DEPTH else "it nests too deep"
        except (ValueError, RecursionError):
            answer, problem = None, "it is not JSON"
        if problem is None:
            checked: dict[str, Any] = answer
            return checked
        self.stop()
        raise PolicyProcessEnded(
            f"the policy's process sent {_short(data)}, which is no answer ({problem}): it was stopped"
        )

    def stop(self) -> int | None:
        """Kills the policy's process (if running); its exit code."""
        if self._process is None:
            return None
        self._process = None
        assert self._finalizer is not None, "set with the process"
        return self._finalizer()  # calls _stop once, and no more at exit
