"""lastmile.recorder."""
