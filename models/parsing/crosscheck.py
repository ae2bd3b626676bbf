"""The LLM's answer against the offline parse of the same instruction.

A small model often answers a two-reference instruction with one tuple; accepted as it is, a
two-constraint placement silently becomes a one-constraint one. The LLM parser therefore parses
every instruction offline too, compares the two here, and answers by a policy
(`LLMConfig.cross_check`, docs/parsing.md "Cross-check"):

    "offline"  the offline parse whenever the two differ and it parsed (the default: best measured)
    "cover"    the offline parse when the LLM left out a reference the offline parse names (and
               named none of its own); otherwise the LLM's answer
    "llm"      the LLM's answer always

Whatever the policy, a difference is never silent: every tuple of the answer carries it in
`ParsedTuple.disagreement`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from ocplace.models.parsing.types import ParsedTuple


@dataclasses.dataclass(frozen=True)
class Comparison:
    dropped: tuple[str, ...] = ()  # references of the offline parse that the LLM's answer lacks
    added: tuple[str, ...] = ()  # references of the LLM's answer that the offline parse lacks
    relations: tuple[tuple[str, str, str], ...] = ()  # (reference, the LLM's relation, the offline one)
    offline_error: str | None = None  # the offline parser's ParseError, when it raised one

    def describe(self) -> str | None:
        """One line for the log and `ParsedTuple.disagreement`; None when the two agree."""
        parts = []
        if self.offline_error is not None:
            parts.append(f"the offline parser could not parse it ({self.offline_error})")
        if self.dropped:
            parts.append(f"the LLM left out {', '.join(map(repr, self.dropped))}")
        if self.added:
            parts.append(f"only the LLM names {', '.join(map(repr, self.added))}")
        parts += [
            f"{name!r}: the LLM says {ours}, the offline parser {theirs}" for name, ours, theirs in self.relations
        ]
        return "; ".join(parts) or None


def same_reference(first: str, second: str) -> bool:
    """Whether two references name the same object: equal, or the words of one a run of the other's
    ("bowl" and "red bowl"; not "red bowl" and "blue bowl")."""
    shorter, longer = sorted((first.split(), second.split()), key=len)
    return any(longer[start : start + len(shorter)] == shorter for start in range(len(longer) - len(shorter) + 1))


def compare(
    llm: Sequence[ParsedTuple], offline: Sequence[ParsedTuple] | None, offline_error: str | None = None
) -> Comparison:
    """Which references each answer names and where their relations differ (`offline` None: it raised).

    References are paired one to one, so "bowl" stands for one of "red bowl" and "blue bowl", never
    for both."""
    if offline is None:
        return Comparison(offline_error=offline_error or "no answer")
    pairs = _pairs(llm, offline)
    dropped = tuple(o.reference for j, o in enumerate(offline) if j not in pairs.values())
    added = tuple(m.reference for i, m in enumerate(llm) if i not in pairs)
    differing = tuple(
        (llm[i].reference, llm[i].relation, offline[j].relation)
        for i, j in pairs.items()
        if llm[i].relation != offline[j].relation
    )
    return Comparison(dropped, added, differing)


def _same_pair(first: ParsedTuple, second: ParsedTuple) -> bool:
    return (first.reference, first.relation) == (second.reference, second.relation)


def _same_name(first: ParsedTuple, second: ParsedTuple) -> bool:
    return first.reference == second.reference


def _named_alike(first: ParsedTuple, second: ParsedTuple) -> bool:
    return same_reference(first.reference, second.reference)


def _alike_pair(first: ParsedTuple, second: ParsedTuple) -> bool:
    return _named_alike(first, second) and first.relation == second.relation


def _pairs(ours: Sequence[ParsedTuple], theirs: Sequence[ParsedTuple]) -> dict[int, int]:
    """Index pairs (ours, theirs) naming the same object, each index used once: identical tuples first,
    then equal names, then names one of which is a run of the other (with the same relation first)."""
    pairs: dict[int, int] = {}
    for matches in (_same_pair, _same_name, _alike_pair, _named_alike):
        for i, mine in enumerate(ours):
            if i not in pairs:
                free = (j for j, other in enumerate(theirs) if j not in pairs.values() and matches(mine, other))
                j = next(free, None)
                if j is not None:
                    pairs[i] = j
    return pairs


def choose(
    policy: str, llm: Sequence[ParsedTuple], offline: Sequence[ParsedTuple] | None, comparison: Comparison
) -> list[ParsedTuple]:
    """The answer `policy` picks, every tuple carrying the disagreement (if any)."""
    use_offline = offline is not None and (
        (policy == "cover" and comparison.dropped and not comparison.added)
        or (policy == "offline" and comparison.describe() is not None)
    )
    note = comparison.describe()
    chosen = offline if use_offline and offline is not None else llm
    return [dataclasses.replace(item, disagreement=note) for item in chosen]
