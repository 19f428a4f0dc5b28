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
