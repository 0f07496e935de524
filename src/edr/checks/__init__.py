"""What the suite checks: a command line and a config before any work starts (one line per
failure), and a stop signal once a step while it works."""
