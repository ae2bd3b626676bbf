"""Table I row "Ours w/o LLM": no parser; the top visual tokens and an MLP's relations."""

TABLE_ROW = 6
