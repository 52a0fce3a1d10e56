"""lastmile.planning."""
