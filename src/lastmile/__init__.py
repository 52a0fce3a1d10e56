"""lastmile: an autonomy stack, simulator and service tooling for low-speed autonomous shuttles."""

__version__ = "0.1.0"
