"""Joint, feasibility-aware grounding (beyond the paper): one token per reference, chosen together.

The paper grounds each reference at its own argmax and only then asks whether a placement exists. But the
instruction says that one does, and two different names almost always mean two different objects. Here,
per scene, each of the L references keeps its `top_k` tokens; an assignment takes one of them per reference
(`top_k ** L` assignments). It is *consistent* when references with the same name take the same token and
references with different names take different objects (the table may serve both); its joint probability is
the product of its references' probabilities (the grounding treats them as independent). It is *feasible*
when the tuples grounded on its tokens leave a cell where the held object fits: exactly the sampler's
support (`metric.grid_terms`: inside the table, clear of every box, every tuple's region), so a feasible
assignment never ends in `NoFeasiblePlacement`. The choice is the consistent, feasible assignment of highest
joint probability (ties: the earlier in rank order); when there is none, the argmax assignment, flagged.

Pure JAX: `choose_assignments` is jitted, vmapped over assignments and mapped over scenes. The tuple regions
are computed once per candidate (L x top_k of them), and an assignment's region is their AND.
"""

from __future__ import annotations

import functools
import itertools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ocplace.sim import metric, relations

SCENES_PER_STEP = 8  # scenes mapped together; each holds (assignments, nx, ny) booleans


class JointProblem(NamedTuple):
    """A batch of scenes to ground jointly; every field has a leading scene axis `B`."""

    probabilities: Any  # (B, L, T) float32 P over the visual tokens per reference; 0 on padded tokens
    tuple_mask: Any  # (B, L) bool: a parsed reference (False: padding)
    relation: Any  # (B, L) int32 index into relations.RELATION_NAMES
    same_name: Any  # (B, L, L) bool: the two references have the same (normalised) name
    num_boxes: Any  # (B,) int32 N: tokens 0..N-1 are objects, N is the table, the rest padding
    token_boxes: Any  # (B, T, 2, 2) float32 table-frame AABB of each object token (zeros elsewhere)
    boxes: Any  # (B, NB, 2, 2) float32 AABBs the held object must not overlap
    box_mask: Any  # (B, NB) bool
    half_extents: Any  # (B, 2) float32 the held object's footprint


class JointChoice(NamedTuple):
    tokens: Any  # (B, L) int32 the chosen token per reference (0 on padded references)
    log_probability: Any  # (B,) float32 log of the chosen assignment's joint probability
    found: Any  # (B,) bool: a consistent feasible assignment exists (False: the argmax assignment, flagged)
    consistent: Any  # (B,) int32 consistent assignments among the candidates
    feasible: Any  # (B,) int32 consistent and feasible ones


@functools.cache
def rank_combinations(top_k: int, num_tuples: int) -> np.ndarray:
    """`(top_k ** num_tuples, num_tuples)` int32: every assignment as each reference's candidate rank, the
    argmax assignment (all ranks 0) first, then in lexicographic order."""
    return np.array(list(itertools.product(range(top_k), repeat=num_tuples)), np.int32).reshape(-1, num_tuples)


def _object_relations() -> np.ndarray:
    """`(9,)` bool: the relation applies to an object reference (else to the table only)."""
    return np.array([relations.relation(name).applies_to_objects for name in relations.RELATION_NAMES])


def _scene(problem: JointProblem, top_k: int, grid: metric.Grid) -> JointChoice:
    """One scene's choice (fields without the scene axis)."""
    num_tuples = problem.probabilities.shape[0]
    top_p, top_tokens = jax.lax.top_k(problem.probabilities, top_k)  # (L, k), the lower token first on ties
    ranks = jnp.asarray(rank_combinations(top_k, num_tuples))  # (A, L)
    tokens = jnp.take_along_axis(top_tokens, ranks.T, axis=1).T  # (A, L)
    probability = jnp.take_along_axis(top_p, ranks.T, axis=1).T  # (A, L)
    used = problem.tuple_mask

    is_object = tokens < problem.num_boxes
    fits_relation = ~is_object | jnp.asarray(_object_relations())[problem.relation][None, :]
    candidate_ok = (probability > 0) & (tokens <= problem.num_boxes) & fits_relation
    each_ok = jnp.where(used[None, :], candidate_ok, ranks == 0)  # a padded reference keeps its first rank
    same_token = tokens[:, :, None] == tokens[:, None, :]  # (A, L, L)
    clash = jnp.where(problem.same_name[None], ~same_token, same_token & is_object[:, :, None])
    clash &= used[None, :, None] & used[None, None, :]
    consistent = jnp.all(each_ok, axis=1) & ~jnp.any(clash, axis=(1, 2))
    log_probability = jnp.sum(jnp.where(used[None, :], jnp.log(probability), 0.0), axis=1)

    feasible = _feasible(problem, top_tokens, ranks, top_k, grid)
    score = jnp.where(consistent & feasible, log_probability, -jnp.inf)
    found = jnp.any(consistent & feasible)
    chosen = jnp.where(found, jnp.argmax(score), 0)
    return JointChoice(
        tokens=jnp.where(used, tokens[chosen], 0),
        log_probability=log_probability[chosen],
        found=found,
        consistent=jnp.sum(consistent, dtype=jnp.int32),
        feasible=jnp.sum(consistent & feasible, dtype=jnp.int32),
    )


def _feasible(problem: JointProblem, top_tokens, ranks, top_k: int, grid: metric.Grid):
    """`(A,)` bool: the assignment's tuples leave a cell where the held object fits (the sampler's support)."""
    num_tuples = top_tokens.shape[0]
    candidates = top_tokens.reshape(-1)  # (L * k,): reference l's rank-r token at l * k + r
    repeat = functools.partial(jnp.repeat, repeats=top_k, axis=0)
    candidate_problem = metric.PlacementProblem(
        relation=repeat(problem.relation),
        reference_is_object=candidates < problem.num_boxes,
        reference_box=problem.token_boxes[candidates],
        tuple_mask=repeat(problem.tuple_mask),
        boxes=problem.boxes,
        box_mask=problem.box_mask,
        half_extents=problem.half_extents,
    )
    terms = metric.grid_terms(candidate_problem, grid, xp=jnp)
    holds = jax.vmap(terms.tuple_holds)(jnp.arange(num_tuples * top_k))  # (L * k, nx, ny)
    index = jnp.arange(num_tuples)[None, :] * top_k + ranks  # (A, L)

    def add_tuple(tuple_index, region):
        return region & holds[index[:, tuple_index]]

    region = jnp.broadcast_to(terms.fits(jnp), (len(ranks), *grid.shape))
    region = jax.lax.fori_loop(0, num_tuples, add_tuple, region)
    return jnp.any(region, axis=(1, 2))


@functools.partial(jax.jit, static_argnames=("top_k", "grid"))
def choose_assignments(problem: JointProblem, top_k: int, grid: metric.Grid = metric.DEFAULT_GRID) -> JointChoice:
    """The joint choice for every scene of `problem`; `top_k` is clipped to the number of tokens T."""
    top_k = min(top_k, problem.probabilities.shape[-1])
    return jax.lax.map(lambda scene: _scene(scene, top_k, grid), problem, batch_size=SCENES_PER_STEP)
