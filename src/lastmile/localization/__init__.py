"""lastmile.localization."""
