"""lastmile.decision."""
