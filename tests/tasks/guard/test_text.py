"""Pre-guard: disguised blocked terms are caught, legitimate words that contain them are not."""

import pytest
from pydantic import ValidationError

from tasks.guard.config import GuardConfig
from tasks.guard.text import GuardError, check_fields, check_text, scan_fields, scan_text, text_fields


@pytest.mark.parametrize("text, term", [
    ("kill the operator", "kill"),
    ("KILL", "kill"),
    ("killing", "kill"),                # inflection, via the lemma
    ("he was killed.", "kill"),
    ("k1ll", "kill"),                   # leetspeak, 1 as i ...
    ("ki11", "kill"),                   # ... and as l
    ("k!ll", "kill"),
    ("$h00ting", "shoot"),              # leetspeak and inflection together
    ("w34p0ns", "weapon"),
    ("n@ked", "naked"),
    ("s.h.o.o.t the worker", "shoot"),  # punctuation inside a word
    ("k-i-l-l", "kill"),
    ("s h o o t", "shoot"),             # spaced-out letters
    ("a k i l l", "kill"),
    ("sh oot", "shoot"),                # a word split where one half is no word
    ("kil l", "kill"),
    ("kiiiill", "kill"),                # repeated letters
    ("murdr", "murder"),                # a misspelling (edit distance 1) of a 5+ letter term
    ("Ｋｉｌｌ", "kill"),                 # full-width letters
    ("kіll", "kill"),                   # a Cyrillic i
    ("k\u200bill", "kill"),             # a zero-width space
    ("bombs away", "bomb"),
    ("child abuse", "child abuse"),     # phrases
    ("self-harm", "self harm"),
    ("a gun on the shelf", "gun"),
])
def test_blocked(text, term):
    assert term in {m.term for m in scan_text(text)}
    with pytest.raises(GuardError, match=term):
        check_text(text, "task.instruction")


@pytest.mark.parametrize("text", [
    "pick the brown package out of the bin and lift it clear",
    "skill", "skilled operators", "Scunthorpe", "therapist", "assessment", "Sussex", "sextant",
    "short", "shook", "grape", "stable", "gunpowder-free", "mass acre",  # real words, whole-word matching
    "hit the kill switch", "kill-switch", "killswitch",  # the allowlist
    "use the glue gun", "a photo shoot", "visible to the naked eye",
    "1 2 3 go", "R2D2 moves 6 kg", "ur5e + 2f85 gripper", "x y z", "",
])
def test_allowed(text):
    assert scan_text(text) == []
    assert check_text(text) == text


def test_error_names_field_term_and_what_matched():
    with pytest.raises(GuardError) as info:
        check_text("please k1ll it", "stressors[1].description")
    assert str(info.value) == "stressors[1].description: blocked term 'kill' (found 'k1ll')"
    assert (info.value.field, info.value.term, info.value.found) == ("stressors[1].description", "kill", "k1ll")


def test_config_extends_both_lists_and_can_turn_off():
    assert scan_text("zap the crate") == []
    assert scan_text("zapping the crate", GuardConfig(blocklist=("zap",)))[0].term == "zap"
    assert scan_text("a gun", GuardConfig(allowlist=("gun",))) == []
    assert scan_text("kill", GuardConfig(allowlist=("killing",)))[0].term == "kill"  # no allowing by lemma
    assert scan_text("a glue gun on a gun rack", GuardConfig())[0].found == "gun"  # allowing a phrase is not allowing the word
    assert scan_text("kill", GuardConfig(enabled=False)) == []
    assert scan_text("murdr") and not scan_text("murdr", GuardConfig(fuzzy=False))
    with pytest.raises(ValidationError):
        GuardConfig(blocklist=(" ",))
    with pytest.raises(ValidationError):
        GuardConfig(method="erase")


def test_text_fields_walk_dotted_paths():
    value = {"task": {"instruction": "x"}, "cameras": [{"name": "a"}, {"name": "b"}], "n": 3}
    assert list(text_fields(value)) == [("task.instruction", "x"), ("cameras[0].name", "a"), ("cameras[1].name", "b")]
    with pytest.raises(GuardError, match=r"^cameras\[1\]\.name: blocked term 'gun'"):
        check_fields({"cameras": [{"name": "ok"}, {"name": "gun_cam"}]})
    assert [f for f, _ in scan_fields({"a": "bomb", "b": ["fine", "n@ked"]})] == ["a", "b[1]"]
