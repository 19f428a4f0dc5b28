"""Prefect flows and the CLI. Importing this package points Prefect at Worldline's settings.

Prefect reads PREFECT_HOME when it is first imported, so it is set here, before any flow
module imports prefect. Values a user exported themselves win.
"""

import os
import sys
from pathlib import Path

from schemas.settings import Settings, SettingsError


def configure_prefect(settings: Settings | None = None) -> Settings:
    settings = settings or Settings()
    home = Path(os.environ.setdefault("PREFECT_HOME", str(settings.prefect_home_path.resolve())))
    # Prefect creates its home without parents and its SQLite file then cannot open.
    try:
        home.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SettingsError(f"Prefect's home {home} (from WORLDLINE_DATA_ROOT or PREFECT_HOME) cannot be "
                            f"created: {exc.strerror}") from None
    # No network here beyond package registries: telemetry would only log failures.
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_UI_SHOW_PROMOTIONAL_CONTENT", "false")
    # Prefect's 20 s default is too short for a busy two-core machine (seen failing here).
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
    return settings


try:
    configure_prefect()
except SettingsError as _error:  # a wrong WORLDLINE_ variable: say which, not a traceback
    print(f"worldline: {_error}", file=sys.stderr)
    raise SystemExit(2) from None
