"""The one runtime settings class. Every field reads from WORLDLINE_<NAME>."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError
from pydantic_settings import BaseSettings, SettingsConfigDict

from schemas import paths


class SettingsError(ValueError):
    """One line: each WORLDLINE_ variable that is wrong, its value and the problem."""


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="WORLDLINE_", frozen=True, extra="ignore")

    def __init__(self, **values):
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise SettingsError("; ".join(
                f"WORLDLINE_{'_'.join(map(str, e['loc'])).upper()}={e.get('input')!r}: {e['msg']}"
                for e in exc.errors())) from None

    data_root: Path = Field(Path(".worldline"), description="where artifacts, the warehouse and Prefect's home live")
    warehouse: Path | None = Field(None, description="DuckDB lineage file; default <data_root>/lineage.duckdb")
    prefect_home: Path | None = Field(None, description="PREFECT_HOME; default <data_root>/prefect")
    robots_root: Path = Field(Path("../shared/data/robots"), description="where MJCF paths in manifests resolve")
    task_runner: Literal["local", "process", "ray"] = "local"
    ray_address: str | None = None
    workers: int = Field(2, ge=1, le=256)
    lock_timeout: float = Field(60.0, ge=0, le=86_400, description="seconds a writer waits for another process "
                                "writing to the same data root (or holding the warehouse) before it gives up, exit 4")

    report_pages: bool = Field(True, description="each flow run writes its HTML report page "
                               "(<data_root>/reports/<run id>.html) and publishes it as Prefect artifacts")

    @property
    def warehouse_path(self) -> Path:
        return self.warehouse or self.data_root / paths.WAREHOUSE_FILE

    @property
    def prefect_home_path(self) -> Path:
        return self.prefect_home or self.data_root / paths.PREFECT_DIR
