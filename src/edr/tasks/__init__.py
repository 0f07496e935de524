"""Tasks: what one run does with its representation (and, later, its backbone)."""
