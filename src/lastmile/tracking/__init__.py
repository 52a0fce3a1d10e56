"""lastmile.tracking."""
