"""Guardrails, offline (issue 10).

- ``tasks.guard.text``: the pre-guard on manifests, captions and prompts (``check_text``,
  ``check_fields``); no OpenCV import, so manifest loading stays light.
- ``tasks.guard.faces``: the post-guard on frames (``guard_frames``, ``guard_stream``).
- ``tasks.guard.clip``: ``guard_clip`` re-encodes an MP4 with faces hidden.
- ``tasks.guard.lineage``: decisions as warehouse rows.
- ``tasks.guard.config``: ``GuardConfig`` for all of them.
"""
