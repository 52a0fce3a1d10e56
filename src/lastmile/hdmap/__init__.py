"""lastmile.hdmap."""
