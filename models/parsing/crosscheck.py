"""The LLM's answer against the offline parse of the same instruction.

A small model often answers a two-reference instruction with one tuple; accepted as it is, a
two-constraint placement silently becomes a one-constraint one. The LLM parser therefore parses
every instruction offline too, compares the two here, and answers by a policy
(`LLMConfig.cross_check`, docs/parsing.md "Cross-check"):

    "cover"    the offline parse when the LLM left out a reference the offline parse names (and
               named none of its own); otherwise the LLM's answer
    "offline"  the offline parse whenever the two differ and it parsed
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
    """Which references each answer names and where their relations differ (`offline` None: it raised)."""
    if offline is None:
        return Comparison(offline_error=offline_error or "no answer")
    dropped = tuple(o.reference for o in offline if not any(same_reference(o.reference, m.reference) for m in llm))
    added = tuple(m.reference for m in llm if not any(same_reference(m.reference, o.reference) for o in offline))
    differing = []
    for mine in llm:
        theirs = [o.relation for o in offline if same_reference(mine.reference, o.reference)]
        if theirs and mine.relation not in theirs:
            differing.append((mine.reference, mine.relation, theirs[0]))
    return Comparison(dropped, added, tuple(differing))


def choose(
    policy: str, llm: Sequence[ParsedTuple], offline: Sequence[ParsedTuple] | None, comparison: Comparison
) -> list[ParsedTuple]:
    """The answer `policy` picks, every tuple carrying the disagreement (if any)."""
    use_offline = offline is not None and (
        (policy == "cover" and comparison.dropped and not comparison.added)
        or (policy == "offline" and comparison.describe() is not None)
    )
    note = comparison.describe()
    return [dataclasses.replace(item, disagreement=note) for item in (offline if use_offline else llm)]
