"""`worldline controls`: edge and blur controls of videos (docs/transfer.md)."""

from __future__ import annotations

from flows.cli_shell import app, command, fail, out, writing
from flows.params_data import ControlsParams


@command(app, ControlsParams)
def controls(params: ControlsParams) -> None:
    """Edge (Canny) and blur controls of a video, an episode's cameras or a folder of videos, as
    MP4s beside each video (an episode's in its controls/ folder) or under --out (Prefect flow
    `controls`); what is not a video is refused in one line."""
    from tasks.controls.check import ControlError
    from tasks.controls.sources import find_sources

    try:
        find_sources(params.source, params.out)
    except ControlError as exc:
        fail(str(exc))
    from flows.controls import controls as controls_flow

    writing()
    result = controls_flow(**params.model_dump())
    out.print(f"{result['videos']} videos, {result['new']} given controls: {len(result['written'])} files written",
              highlight=False)
