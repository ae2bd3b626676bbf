"""Parser configuration: frozen dataclasses with a default and a tiny variant for tests."""

from __future__ import annotations

import dataclasses

from ocplace.models.parsing import text

PARSER_NAMES = ("offline", "offline-snap", "llm")


@dataclasses.dataclass(frozen=True)
class SnapConfig:
    encoder: str = "minilm"  # "minilm", or "backbone": a grounding backbone's text tower
    source: str | None = None  # minilm: a model directory (None: the package's); backbone: its spec
    # Chosen so that spatial words the encoder confuses (it puts "rear" nearer "front" than
    # "back") are refused rather than guessed; see docs/parsing.md.
    min_similarity: float = 0.7
    min_margin: float = 0.1


@dataclasses.dataclass(frozen=True)
class OfflineConfig:
    max_chars: int = text.DEFAULT_MAX_CHARS
    relation_source: str = "lexicon"  # "lexicon", or "encoder": snap every relation phrase
    snap: SnapConfig = SnapConfig()


@dataclasses.dataclass(frozen=True)
class LLMConfig:
    base_url: str = "http://127.0.0.1:8000/v1"  # any OpenAI-compatible server
    model: str = "gpt-4o-mini"
    api_key_env: str = "OCPLACE_LLM_API_KEY"  # unset: no Authorization header (local servers)
    timeout_s: float = 20.0
    max_attempts: int = 3
    backoff_s: float = 0.5  # doubled after each failed attempt
    temperature: float = 0.0
    use_cache: bool = True
    cache_subdir: str = "parser"  # under ocplace.paths.cache_dir()


@dataclasses.dataclass(frozen=True)
class ParsingConfig:
    parser: str = "offline"
    offline: OfflineConfig = OfflineConfig()
    llm: LLMConfig = LLMConfig()


def default_config() -> ParsingConfig:
    return ParsingConfig()


def smoke_config() -> ParsingConfig:
    """Fast retries and short timeouts, for tests against a local server."""
    return ParsingConfig(llm=LLMConfig(timeout_s=1.0, max_attempts=3, backoff_s=0.01))
