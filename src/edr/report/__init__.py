"""The paper's tables and figures, rendered from run and bench records (``edr-tables``)."""
