"""lastmile.sim."""
