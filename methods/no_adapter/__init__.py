"""Table I row "Ours w/o Adapter": Ours' policy on the plain backbone; it learns nothing."""

TABLE_ROW = 3
