"""Audit queries ship as .sql files with `$name` parameters, always bound, never formatted in."""

from __future__ import annotations

import re
from importlib import resources

PARAM = re.compile(r"\$([a-z_]+)")


class UnknownAudit(LookupError):
    pass


def available() -> list[str]:
    folder = resources.files("warehouse").joinpath("audits")
    return sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".sql"))


def load(name: str) -> str:
    if name not in available():
        raise UnknownAudit(f"unknown audit {name!r}; available: {', '.join(available())}")
    return resources.files("warehouse").joinpath("audits", f"{name}.sql").read_text()


def describe(name: str) -> str:
    return load(name).splitlines()[0].lstrip("- ").strip()


def parameters(sql: str) -> list[str]:
    return sorted(set(PARAM.findall(sql)))


def bind(name: str, given: dict[str, str | None]) -> tuple[str, dict[str, str]]:
    """The audit's SQL and exactly the parameters it names; a missing one is an error."""
    sql = load(name)
    needed = parameters(sql)
    missing = [p for p in needed if not given.get(p)]
    if missing:
        raise ValueError(f"audit {name!r} needs --{' --'.join(missing)}")
    return sql, {p: given[p] for p in needed}
