"""The methods of Table I, one module per row: its recipe type, how it trains and how a run loads."""
