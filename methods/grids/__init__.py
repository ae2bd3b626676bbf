"""Table I row "Raw Image Grids": the table cut into cells, the best-matching cell chosen."""

TABLE_ROW = 4
