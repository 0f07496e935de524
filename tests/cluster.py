"""Where a Slurm cluster answers: the environment its commands (sinfo, sbatch) need."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

LOCAL_CLUSTER = Path(__file__).resolve().parents[1] / "sweeps" / "slurm-local.sh"
NO_CLUSTER = 'no Slurm cluster up (start one here: eval "$(sweeps/slurm-local.sh start)")'


def slurm_environment() -> dict[str, str] | None:
    """This process's environment if its ``sinfo`` reaches a cluster with a usable node, with
    the local cluster's SLURM_CONF where none is set (``slurm-local.sh status`` prints it when
    up); None when no cluster answers."""
    if shutil.which("sinfo") is None:
        return None
    env = dict(os.environ)
    if "SLURM_CONF" not in env:
        try:
            status = subprocess.run(["bash", str(LOCAL_CLUSTER), "status"], capture_output=True,
                                    text=True, timeout=60)  # fmt: skip
        except subprocess.TimeoutExpired:
            return None
        if status.returncode != 0:
            return None  # no local cluster, and no other named by SLURM_CONF
        env["SLURM_CONF"] = status.stdout.strip().split("=", 1)[1]
    elif not Path(env["SLURM_CONF"]).is_file():
        return None  # a stale SLURM_CONF: sinfo would wait on DNS lookups for minutes
    try:
        states = subprocess.run(["sinfo", "-h", "-o", "%t"], env=env, capture_output=True,
                                text=True, timeout=30)  # fmt: skip
    except subprocess.TimeoutExpired:
        return None
    return env if re.search(r"idle|mix|alloc", states.stdout) else None
