"""softrom_gym."""
