"""Post-training a learned policy on new demonstrations, whichever kind it is.

A state policy (``bc``) learns from what the scripted controller reads; a vision policy
(``vision``) from what the same cameras showed. Both start from the old weights and keep its
normalisation statistics, so its inputs and outputs keep their meaning.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from schemas.manifest import ScenarioManifest
from tasks.policy import bc, vision, vision_train
from tasks.policy.base import Policy

Learned = bc.BCPolicy | vision.VisionPolicy


def kind_of(policy: Policy) -> str:
    """``bc`` or ``vision``: the prefix a policy name takes and its checkpoint folder's model."""
    if isinstance(policy, bc.BCPolicy):
        return "bc"
    if isinstance(policy, vision.VisionPolicy):
        return "vision"
    raise ValueError(f"policy {policy.name}: only learned policies (bc:, vision:) can be post-trained")


def model_name(policy: Policy) -> str:
    return f"{kind_of(policy)}-policy"


def demonstrations(parent: ScenarioManifest, policy: Learned, derived: Sequence[ScenarioManifest],
                   counts: Sequence[int], note: Callable[[str], None] = print):
    """Scripted demonstrations on the derived manifests' new seeds (what the policy observes),
    plus the policy's own training seeds when it was trained on this parent; a manifest the
    scripted controller never solves adds nothing (and is noted)."""
    if isinstance(policy, vision.VisionPolicy):
        def collect(manifest, seeds):
            return vision.collect(manifest, seeds, policy.spec)
    else:
        collect = bc.collect
    parts = []
    if policy.meta.get("manifest_hash") == parent.sha256 and policy.meta.get("train_seeds"):
        parts.append(collect(parent, policy.meta["train_seeds"]))
    for m, n in zip(derived, counts):
        try:
            parts.append(collect(m, [m.seed + i for i in range(n)]))
        except ValueError as exc:  # no successful demonstration on these seeds
            note(f"{m.name}: {exc}")
    if not parts:
        raise ValueError("no successful demonstrations on the derived manifests to post-train on")
    if isinstance(policy, vision.VisionPolicy):
        merged = parts[0]
        for part in parts[1:]:
            merged = merged + part
        return merged
    from tasks.loop import merge

    return merge(parts)


def samples(demos) -> int:
    return int(len(demos.act))


def post_train(policy: Learned, demos, config: bc.TrainConfig, folder: Path, parent: ScenarioManifest,
               extra: dict) -> list[dict]:
    """The old policy fine-tuned on ``demos``, saved under ``folder``; the training history."""
    if isinstance(policy, vision.VisionPolicy):
        model, history = vision_train.train_vision(demos, policy.spec, config, start=policy.model)
        vision_train.save_checkpoint(model, policy.spec, folder, parent, config, extra)
    else:
        model, history = bc.train_bc(demos, config, start=policy.model)
        bc.save_checkpoint(model, folder, parent, config, extra)
    return history
