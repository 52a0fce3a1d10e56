"""lastmile.evaluation: metrics from run logs, the closed-loop score, and reports with plots."""
