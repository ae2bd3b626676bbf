"""Table I row "CLIPort-Place": an affordance map over the table's pixels."""

TABLE_ROW = 5
