"""lastmile.runner."""
