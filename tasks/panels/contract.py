"""Refuse comparing panels (or a policy and a panel) whose contracts differ, naming what differs."""

from __future__ import annotations

from collections.abc import Mapping

from schemas.panel import PanelContract, contract_hash


class PanelContractError(ValueError):
    """Panels with different contracts: one line naming each field that differs."""


def _camera_text(cam: dict) -> str:
    w, h = cam["resolution"]
    return (f"{cam['name']} ({cam['mount']} at {tuple(cam['position'])} looking at {tuple(cam['look_at'])}, "
            f"{w}x{h} @ {cam['fps']:g} fps, fovy {cam['fovy_deg']:g})")


def contract_differences(a: PanelContract, b: PanelContract) -> list[str]:
    """Each differing contract field as 'field: A vs B' (cameras compared one by one)."""
    da, db = a.model_dump(mode="json"), b.model_dump(mode="json")
    out = []
    for field in type(a).model_fields:
        if da[field] == db[field]:
            continue
        if field == "cameras":
            ca, cb = {c["name"]: c for c in da[field]}, {c["name"]: c for c in db[field]}
            if list(ca) != list(cb):
                out.append(f"camera layout: {', '.join(ca)} vs {', '.join(cb)}")
            for name in ca.keys() & cb.keys():
                if ca[name] != cb[name]:
                    out.append(f"camera {_camera_text(ca[name])} vs {_camera_text(cb[name])}")
        elif field == "embodiment":
            out.append(f"embodiment: {da[field]} vs {db[field]}")
        else:
            label = {"horizon_s": "horizon", "target": "evaluation target"}.get(field, field)
            out.append(f"{label}: {da[field]!r} vs {db[field]!r}")
    return out


def check_same_contract(contracts: Mapping[str, PanelContract]) -> str:
    """All contracts equal, or PanelContractError naming the first one that differs from the
    first and every field in which it differs. Returns the shared contract hash."""
    items = list(contracts.items())
    if not items:
        raise ValueError("no contracts to compare")
    first_name, first = items[0]
    for name, other in items[1:]:
        if contract_hash(other) != contract_hash(first):
            diff = "; ".join(contract_differences(first, other))
            raise PanelContractError(f"cannot compare {first_name} with {name}: their contracts differ in {diff}")
    return contract_hash(first)
