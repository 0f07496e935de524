"""The paper's Figure 2b as a table: what each representation does, from the properties every
representation class declares (``Representation.features``), one row per config under
``conf/representation/``."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import pandas as pd
import yaml
from hydra.utils import get_class

from edr import CONF_DIR
from edr.report.render import Table


def _target(config: Path) -> str:
    """The ``_target_`` of a representation config, following its defaults (``- edr``)."""
    node = yaml.safe_load(config.read_text())
    if "_target_" in node:
        return node["_target_"]
    parent = next(d for d in node["defaults"] if d != "_self_")
    return _target(config.with_name(f"{parent}.yaml"))


def features_table() -> Table:
    rows = []
    for config in sorted((Path(CONF_DIR) / "representation").glob("*.yaml")):
        cls = get_class(_target(config))
        rows.append(
            {
                "Config": config.stem,
                "Class": cls.__name__,
                **{k.replace("_", " ").capitalize(): v for k, v in asdict(cls.features).items()},
            }
        )
    return Table(
        "figure2b_features",
        "Figure 2b: what each representation does (declared by its class)",
        pd.DataFrame(rows),
        pd.DataFrame(),
        from_code=True,
        notes=[
            "Generated from `Representation.features` of each class behind "
            "conf/representation/*.yaml: no measurement, no runs."
        ],
    )
