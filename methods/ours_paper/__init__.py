"""Row "Ours, paper's adapters": Ours with the paper's adapter recipe, beside rule A's."""

TABLE_ROW = 2
