"""Object and texture split names shared by the library, scenes and the dataset.

A leaf module, cheap to import: the CLI builds its `--split` choices from it.
"""

# seen: training (and pretraining) objects; unseen: the unseen_obj test subset's objects, mostly
# new instances of seen categories; unseen_cat: objects of categories no seen object belongs to
# (docs/library.md states the rule).
LIBRARY_SPLITS = ("seen", "unseen", "unseen_cat")
TEXTURE_SPLITS = ("seen", "unseen")  # table textures; unseen_cat scenes use the unseen ones
