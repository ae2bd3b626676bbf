"""Parser configuration: frozen dataclasses and their default."""

from __future__ import annotations

import dataclasses
import urllib.parse

from ocplace.errors import LLMConfigError
from ocplace.models.parsing import text

PARSER_NAMES = ("offline", "offline-snap", "llm")
# What the LLM parser answers when its answer and the offline parse disagree (docs/parsing.md, "Cross-check").
CROSS_CHECK_POLICIES = ("offline", "cover", "llm")


@dataclasses.dataclass(frozen=True)
class SnapConfig:
    encoder: str = "minilm"  # "minilm", or "backbone": a grounding backbone's text tower
    source: str | None = None  # minilm: a model directory (None: the package's); backbone: its spec
    # Chosen so that spatial words the encoder confuses (it puts "rear" nearer "front" than
    # "back") are refused rather than guessed; see docs/parsing.md.
    min_similarity: float = 0.7
    min_margin: float = 0.1


@dataclasses.dataclass(frozen=True)
class GrammarConfig:
    max_chars: int = text.DEFAULT_MAX_CHARS
    relation_source: str = "lexicon"  # "lexicon", or "encoder": snap every relation phrase
    snap: SnapConfig = SnapConfig()


# The longest a parse may wait, and a request last: beyond it (inf included) the watchdog's timer and the
# socket timeout overflow; a NaN would silently remove the deadline.
MAX_WAIT_S = 86_400


@dataclasses.dataclass(frozen=True)
class LLMConfig:
    """The endpoint and its limits; a parse waits at most `deadline_s` (then the offline parser
    answers), whatever the endpoint does. See docs/reliability.md."""

    base_url: str = "http://127.0.0.1:8080/v1"  # any OpenAI-compatible server (8080: `make llm-server`)
    model: str = "gpt-4o-mini"
    api_key_env: str = "OCPLACE_LLM_API_KEY"  # unset: no Authorization header (local servers)
    timeout_s: float = 20.0  # one request, connect to last body byte (wall clock)
    deadline_s: float = 30.0  # the whole parse: every attempt and every back-off
    max_body_bytes: int = 1_000_000  # a chat completion is a few KB; more is refused unread
    max_attempts: int = 3
    backoff_s: float = 0.5  # doubled after each failed attempt
    temperature: float = 0.0  # at 0 an invalid answer is final: the same request gets it again
    # Four tuples of JSON are under 100 tokens; a model that rambles is cut here, not at its context limit.
    max_tokens: int = 200
    json_mode: bool = True  # ask for `response_format` JSON; dropped for a server that refuses it
    cross_check: str = "offline"  # one of CROSS_CHECK_POLICIES; chosen on the dev and seen sets (docs/parsing.md)
    use_cache: bool = True
    cache_subdir: str = "parser"  # the cache folder of answers (`ocplace.paths.llm_cache`)

    def __post_init__(self):
        check_base_url(self.base_url, self.api_key_env)
        for name in ("timeout_s", "deadline_s"):  # `not 0 < x <= max` also refuses NaN
            if not 0 < getattr(self, name) <= MAX_WAIT_S:
                raise LLMConfigError(
                    f"the LLM parser's {name} must be a number of seconds above 0 and at most {MAX_WAIT_S:,} "
                    f"(a day), got {getattr(self, name)}"
                )
        if not 0 <= self.backoff_s <= MAX_WAIT_S or not 0 <= self.temperature <= 2:
            raise LLMConfigError(
                f"the LLM parser's backoff_s must be 0 to {MAX_WAIT_S:,} seconds and its temperature 0 to 2, got "
                f"{self.backoff_s} and {self.temperature}"
            )
        if min(self.max_body_bytes, self.max_attempts, self.max_tokens) <= 0:
            raise LLMConfigError("the LLM parser's max_body_bytes, max_attempts and max_tokens must all be positive")
        if self.cross_check not in CROSS_CHECK_POLICIES:
            raise LLMConfigError(f"cross_check must be one of {CROSS_CHECK_POLICIES}, got {self.cross_check!r}")


def check_base_url(url: str, api_key_env: str) -> None:
    """Raises LLMConfigError unless `url` is an http(s) URL a request can be sent to.

    Checked before any request: urllib would also open file:// and ftp:// URLs.
    """
    example = "give an http:// or https:// URL such as http://127.0.0.1:8080/v1"
    if "@" in url:  # not echoed: it may hold a password
        raise LLMConfigError(
            f"the LLM base URL must not hold credentials (user:password@); "
            f"{example} and put the API key in ${api_key_env}"
        )
    try:
        parts = urllib.parse.urlsplit(url)
        _ = parts.port  # reading the port parses it: "host:abc" and "host:99999" raise
    except ValueError:
        raise LLMConfigError(f"the LLM base URL {url!r} is malformed; {example}") from None
    if parts.scheme not in ("http", "https"):
        raise LLMConfigError(f"the LLM base URL {url!r} does not start with http:// or https://; {example}")
    if not parts.hostname or parts.query or parts.fragment or " " in url or not url.isprintable():
        raise LLMConfigError(f"the LLM base URL {url!r} needs a host and no spaces, query or fragment; {example}")


@dataclasses.dataclass(frozen=True)
class ParsingConfig:
    parser: str = "offline"
    offline: GrammarConfig = GrammarConfig()
    llm: LLMConfig = LLMConfig()


def default_config() -> ParsingConfig:
    return ParsingConfig()
