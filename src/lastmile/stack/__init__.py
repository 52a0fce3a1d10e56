"""lastmile.stack."""
