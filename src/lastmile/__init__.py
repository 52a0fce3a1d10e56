"""lastmile: an autonomy stack, simulator and service tooling for low-speed autonomous shuttles."""
