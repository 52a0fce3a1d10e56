"""lastmile.safety."""
