"""lastmile.core."""
