"""lastmile.fleet."""
