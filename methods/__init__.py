"""The methods of Table I, one folder per row (`recipe.py`, `model.py`, `train.py`, `method.py`), and the contract
and hosts they share (`registry.py` finds the rows)."""
