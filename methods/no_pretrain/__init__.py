"""Table I row "Ours w/o CLIP pre-train": Ours' backbone from random weights."""

TABLE_ROW = 7
