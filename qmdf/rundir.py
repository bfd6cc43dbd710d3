"""Unique run-directory names: date / time to the microsecond plus a random tag (parallel runs never collide)."""

from __future__ import annotations

import datetime as dt
import secrets
from pathlib import Path

ENV_VAR = "QMDF_RUN_NAME"


def new_run_name() -> str:
    now = dt.datetime.now()
    return f"{now:%Y-%m-%d}/{now:%H-%M-%S.%f}-{secrets.token_hex(3)}"


def conf_dir() -> Path:
    """The `conf/` folder shipped beside the package (editable install or source checkout)."""
    return Path(__file__).resolve().parent.parent / "conf"
