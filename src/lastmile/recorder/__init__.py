"""lastmile.recorder: run logs (ego trace, events, agents) written by the runner, read by evaluation."""
