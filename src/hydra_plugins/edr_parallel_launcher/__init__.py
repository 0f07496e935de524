"""edr's Hydra launchers (Hydra finds plugins only under ``hydra_plugins``)."""
