"""lastmile.safety: process-health and reliability monitors, fail-safe arbitration, hardware watchdog."""
