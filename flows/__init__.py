"""Prefect flows and the CLI. Importing this package points Prefect at Worldline's settings.

Prefect reads PREFECT_HOME when it is first imported, so it is set here, before any flow
module imports prefect. Values a user exported themselves win.
"""

import os
from pathlib import Path

from schemas.settings import Settings


def configure_prefect(settings: Settings | None = None) -> Settings:
    settings = settings or Settings()
    home = Path(os.environ.setdefault("PREFECT_HOME", str(settings.prefect_home_path.resolve())))
    # Prefect creates its home without parents and its SQLite file then cannot open.
    home.mkdir(parents=True, exist_ok=True)
    # No network here beyond package registries: telemetry would only log failures.
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_UI_SHOW_PROMOTIONAL_CONTENT", "false")
    # Prefect's 20 s default is too short for a busy two-core machine (seen failing here).
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
    return settings


configure_prefect()
