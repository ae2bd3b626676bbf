"""ocplace: object-centric, language-conditioned object placement."""

__version__ = "0.1.0"
