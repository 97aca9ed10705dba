"""Pure numerical core."""
