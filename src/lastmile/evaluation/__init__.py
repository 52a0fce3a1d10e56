"""lastmile.evaluation."""
