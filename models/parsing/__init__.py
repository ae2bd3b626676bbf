"""Instruction parsing: `<reference, relation>` tuples from free-form text.

    parser = make_parser("offline")
    parser.parse("could you put it behind the red bowl")  # [ParsedTuple('red bowl', 'back', ...)]

Parsers: "offline" (default; lexicon and grammar, sentence-encoder snapping for unknown relation
phrases), "offline-snap" (the same grammar, every relation snapped by the encoder: an ablation),
"llm" (any OpenAI-compatible chat-completions endpoint, falling back to "offline").
"""

from __future__ import annotations

import dataclasses

from ocplace.models.parsing.config import (
    PARSER_NAMES,
    GrammarConfig,
    LLMConfig,
    ParsingConfig,
    SnapConfig,
    default_config,
)
from ocplace.models.parsing.types import ParsedTuple, Parser, as_pairs

__all__ = [
    "PARSER_NAMES",
    "GrammarConfig",
    "LLMConfig",
    "ParsedTuple",
    "Parser",
    "ParsingConfig",
    "SnapConfig",
    "as_pairs",
    "default_config",
    "make_parser",
    "make_snapper",
]


def make_snapper(config: SnapConfig):
    """A Snapper with its encoder loaded (seconds: the model loads and jit-compiles)."""
    from ocplace.models.parsing.encoder import load_encoder
    from ocplace.models.parsing.snapping import Snapper

    encoder = load_encoder(config.encoder, config.source)
    return Snapper(encoder, config.min_similarity, config.min_margin)


def make_parser(name: str | None = None, config: ParsingConfig | None = None) -> Parser:
    """The parser called `name` (default: `config.parser`)."""
    from ocplace.errors import ParseError
    from ocplace.models.parsing.offline import OfflineParser

    config = config or default_config()
    name = name or config.parser
    if name not in PARSER_NAMES:
        raise ParseError(f"unknown parser {name!r}; choose one of {PARSER_NAMES}")
    offline_config = config.offline
    if name == "offline-snap":
        offline_config = dataclasses.replace(offline_config, relation_source="encoder")
    offline = OfflineParser(
        offline_config, lambda: make_snapper(offline_config.snap), name="offline" if name == "llm" else name
    )
    if name != "llm":
        return offline
    from ocplace.models.parsing.llm import LLMParser

    return LLMParser(config.llm, offline, snapper_factory=lambda: offline.snapper)
