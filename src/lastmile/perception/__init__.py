"""lastmile.perception."""
