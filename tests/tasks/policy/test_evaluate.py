"""Summaries of an evaluation: per-episode agreement of a judge with the simulator."""

from tasks.policy.evaluate import agreement


def _episodes(pairs):
    return [{"success": sim, "world": world} for sim, world in pairs]


def test_agreement_splits_the_simulators_successes_from_its_failures():
    # A judge that says success on everything it decides: right on 3 of 4 decided episodes,
    # but on none of the failures, which the balanced figure shows.
    a = agreement(_episodes([(True, True), (True, True), (True, None), (True, True), (False, True)]), "world")
    assert (a["episodes"], a["decided"], a["agree"]) == (5, 4, 3)
    assert (a["successes"], a["successes_agree"], a["failures"], a["failures_agree"]) == (3, 3, 1, 0)
    assert a["balanced"] == 0.5


def test_agreement_without_decisions_or_without_failures():
    a = agreement(_episodes([(True, None), (False, None)]), "world")
    assert a["decided"] == 0 and a["agree"] == 0 and a["balanced"] is None
    b = agreement(_episodes([(True, True), (True, False)]), "world")
    assert b["agree"] == 1 and b["failures"] == 0 and b["balanced"] is None


def _judged(monkeypatch, votes, samples=None, **kw):
    """world_judgement with the rollout and the detector replaced: sample ``seed`` gets ``votes[seed]``."""
    from types import SimpleNamespace

    import numpy as np

    from tasks.policy import evaluate

    monkeypatch.setattr(evaluate, "world_model_rollout", lambda *a, seed=0, **k: seed)
    monkeypatch.setattr(evaluate, "judge_frames", lambda seed, *a, **k: SimpleNamespace(success=votes[seed]))
    cam = SimpleNamespace(name="overhead", fps=10.0)
    variant = SimpleNamespace(cameras=[cam], horizon_s=1.0, evaluation=None, task=SimpleNamespace(instruction="push"),
                              stressors=[])
    done = SimpleNamespace(context=np.zeros((1, 4, 4, 3), np.uint8), actions=np.zeros((5, 2)), control_hz=5.0,
                           package_start=np.zeros(3))
    return evaluate.world_judgement("wm", variant, "overhead", done, ".", samples=samples or len(votes), **kw)


def test_a_sampled_judge_says_how_sure_it_is_and_abstains_when_split(monkeypatch):
    sure = _judged(monkeypatch, [True, True, True, False])
    assert (sure.verdict, sure.sure) == (True, 0.75) and "3 of 4" in sure.reason
    split = _judged(monkeypatch, [True, False, True, False])
    assert split.verdict is None and split.sure == 0.5 and split.reason.startswith("undecided")
    blind = _judged(monkeypatch, [None, None, None])
    assert blind.verdict is None and blind.sure == 0.0
    failing = _judged(monkeypatch, [False, False, None, False], min_sure=0.7)
    assert (failing.verdict, failing.sure) == (False, 0.75)


def test_the_table_carries_the_judges_certainty():
    from tasks.policy.evaluate import EpisodeOutcome, success_table

    outcomes = [EpisodeOutcome("dim", 0, True, "", world=True, world_sure=1.0),
                EpisodeOutcome("dim", 1, False, "", world=None, world_sure=0.5),
                EpisodeOutcome("nominal", 0, True, "", world=True)]
    rows = {r["cell"]: r for r in success_table(outcomes, ["dim", "nominal"])}
    assert rows["dim"]["world_sure"] == 0.75 and rows["nominal"]["world_sure"] is None
    assert rows["all"]["world_sure"] == 0.75 and rows["dim"]["world"] == 1.0


def test_closed_loop_verdicts_get_their_own_column_and_nothing_changes_without_them():
    from tasks.policy.evaluate import EpisodeOutcome, success_table
    from tasks.policy.results import comparison

    plain = [EpisodeOutcome("dim", 0, True, "", world=True), EpisodeOutcome("dim", 1, False, "", world=False)]
    assert "closed" not in plain[0].as_dict() and all("closed" not in r for r in success_table(plain, ["dim"]))
    _, body = comparison([("p", "a", "e1", success_table(plain, ["dim"]))], [o.as_dict() for o in plain])
    assert set(body["spearman"]) == {"sim_vs_world", "sim_vs_detector", "sim_vs_world_cells", "sim_vs_detector_cells"}
    assert set(body["agreement"]) == {"detector", "world"}

    closed = [EpisodeOutcome("dim", 0, True, "", world=True, closed=False, closed_reason="package short of goal"),
              EpisodeOutcome("dim", 1, False, "", world=False, closed=False, closed_reason="package short of goal")]
    rows = {r["cell"]: r for r in success_table(closed, ["dim"])}
    assert rows["dim"]["closed"] == 0.0 and rows["dim"]["world"] == 0.5
    assert closed[0].as_dict()["closed_reason"] == "package short of goal"
    _, body = comparison([("p", "a", "e1", success_table(closed, ["dim"])),
                          ("p", "b", "e2", success_table(plain, ["dim"]))], [o.as_dict() for o in closed + plain])
    assert {"sim_vs_closed", "sim_vs_closed_cells"} <= set(body["spearman"])
    agree = body["agreement"]["closed"]
    assert (agree["episodes"], agree["decided"], agree["successes_agree"], agree["failures_agree"]) == (4, 2, 0, 1)
