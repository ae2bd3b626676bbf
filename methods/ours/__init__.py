"""Table I row "Ours": CLIP-Adapters trained on a frozen backbone's features, placed by the policy."""

TABLE_ROW = 1
