"""lastmile.recorder: run logs for evaluation, the rolling black box (MCAP) and its replay reader."""
