"""lastmile.control."""
