"""Pre-guard: refuse text that names a blocked term, however it is disguised.

Text is normalised (Unicode compatibility form without accents, case-folded, zero-width
characters dropped, common Cyrillic and Greek look-alikes mapped to Latin) and split into
words at whitespace and punctuation. Each word is checked with its leetspeak readings
(``k1ll`` -> kill, ``$h00t`` -> shoot; 1 and | read as both i and l), its lemma (simplemma,
offline: ``killing`` -> kill), and, when simplemma does not know it as an English word, its
misspellings at edit distance 1 (``murdr``). Spacing and punctuation tricks are undone by
also checking each whitespace token with its punctuation removed (``s.h.o.o.t``), runs of
single letters (``s h o o t``) and adjacent pieces of which one is not a word (``sh oot``).

Matching is on whole words, never substrings, so ``skill``, ``Scunthorpe`` and
``therapist`` pass. The allowlist holds words and phrases whose words are never checked,
e.g. ``kill switch`` or ``glue gun``.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from itertools import product
from typing import Any

import simplemma
from pydantic import BaseModel

from tasks.guard.config import GuardConfig

LANG = "en"
_LEET = {"0": "o", "3": "e", "4": "a", "5": "s", "6": "g", "7": "t", "8": "b", "9": "g",
         "@": "a", "$": "s", "+": "t", "!": "i", "€": "e", "£": "l"}
_LEET_AMBIGUOUS = {"1": "il", "|": "il"}
_LOOKALIKES = str.maketrans("аеорсухіјѕкмтвнԁɡαεορτυνκιχ", "aeopcyxijskmtbhdgaeoptuvkix")
_INVISIBLE = dict.fromkeys(map(ord, "\u00ad\u200b\u200c\u200d\u2060\ufeff"))
_WORD_CHARS = "a-z0-9@$!|+€£"
_PART = re.compile(f"[{_WORD_CHARS}]+")
_TRIM = re.compile(r"^[!|.]+|[!|.]+$")  # sentence punctuation at a token's ends is not leetspeak
MAX_VARIANTS = 8
MAX_RUN = 24  # longest run of single letters joined back into words


class GuardError(ValueError):
    """A blocked term in a text field: one line naming the field, the term and what matched."""

    def __init__(self, field: str, term: str, found: str):
        self.field, self.term, self.found = field, term, found
        super().__init__(f"{field}: blocked term {term!r} (found {found!r})")


@dataclass(frozen=True, slots=True)
class TextMatch:
    term: str  # the blocked term, as listed
    found: str  # the text that matched it, as written
    how: str  # word, lemma, fuzzy, joined (punctuation or spacing removed) or phrase


class _Lists:
    """Block and allow lists, lemmatised once."""

    def __init__(self, blocked: list[str], allowed: list[str]):
        self.words: dict[str, str] = {}
        self.phrases: dict[tuple[str, ...], str] = {}
        for term in blocked:
            words = tuple(_lemma(w) for w in _plain_words(term))
            if len(words) == 1:
                self.words[words[0]] = term
                self.words.setdefault(_plain_words(term)[0], term)
            elif words:
                self.phrases[words] = term
        # Allowed words stand as written: allowing "killing" must not allow "kill" through its lemma.
        self.allow_words = {ws[0] for term in allowed if len(ws := _plain_words(term)) == 1}
        self.allow_phrases = [tuple(ws) for term in allowed if len(ws := _plain_words(term)) > 1]
        self.fuzzy_terms = [w for w in self.words if len(w) >= 5]


def _read_list(name: str) -> list[str]:
    text = resources.files("tasks.guard").joinpath(name).read_text(encoding="utf-8")
    return [line.split("#", 1)[0].strip() for line in text.splitlines() if line.split("#", 1)[0].strip()]


@lru_cache(maxsize=16)
def _lists(extra_block: tuple[str, ...], extra_allow: tuple[str, ...]) -> _Lists:
    return _Lists(_read_list("blocklist.txt") + list(extra_block), _read_list("allowlist.txt") + list(extra_allow))


def _normalise(text: str) -> str:
    text = unicodedata.normalize("NFKD", text).translate(_INVISIBLE)
    text = "".join(ch for ch in text if not unicodedata.combining(ch))
    return text.casefold().translate(_LOOKALIKES)


def _plain_words(term: str) -> list[str]:
    return re.findall(r"[a-z]+", _normalise(term))


@lru_cache(maxsize=65536)
def _lemma(word: str) -> str:
    return simplemma.lemmatize(word, lang=LANG)


@lru_cache(maxsize=65536)
def _known(word: str) -> bool:
    return simplemma.is_known(word, lang=LANG)


@lru_cache(maxsize=65536)
def _readings(piece: str) -> tuple[str, ...]:
    """The letter-only readings of a piece: leetspeak decoded (1 and | both ways)."""
    if not any(ch.isalpha() for ch in piece):
        return ()  # a number is not leetspeak
    options = [_LEET_AMBIGUOUS.get(ch) or _LEET.get(ch, ch) for ch in piece]
    ambiguous = [i for i, ch in enumerate(piece) if ch in _LEET_AMBIGUOUS]
    if 2 ** len(ambiguous) > MAX_VARIANTS:
        choices = [("i",) * len(ambiguous), ("l",) * len(ambiguous)]
    else:
        choices = list(product("il", repeat=len(ambiguous)))
    out = []
    for choice in choices:
        chars = list(options)
        for i, ch in zip(ambiguous, choice):
            chars[i] = ch
        word = re.sub(r"[^a-z]", "", "".join(chars))
        if word and word not in out:
            out.append(word)
    return tuple(out)


def _squeeze(word: str) -> str:
    return re.sub(r"(.)\1+", r"\1", word)


def _edit1(a: str, b: str) -> bool:
    """Levenshtein distance of a and b is exactly 1 (or a transposition of neighbours)."""
    if abs(len(a) - len(b)) > 1 or a == b:
        return False
    if len(a) == len(b):
        diff = [i for i in range(len(a)) if a[i] != b[i]]
        return len(diff) == 1 or (len(diff) == 2 and diff[1] == diff[0] + 1
                                  and a[diff[0]] == b[diff[1]] and a[diff[1]] == b[diff[0]])
    short, long_ = (a, b) if len(a) < len(b) else (b, a)
    i = next((k for k in range(len(short)) if short[k] != long_[k]), len(short))
    return short[i:] == long_[i + 1:]


def _match_word(word: str, lists: _Lists, config: GuardConfig, exact_only: bool = False) -> tuple[str, str] | None:
    if word in lists.allow_words:
        return None
    if word in lists.words:
        return lists.words[word], "word"
    lemma = _lemma(word)
    if lemma in lists.allow_words:
        return None
    if lemma in lists.words:
        return lists.words[lemma], "lemma"
    if exact_only:
        return None
    if _known(word):
        return None  # a real word is not a disguise: skill, short, grape
    squeezed = _squeeze(word)
    if squeezed != word:  # kiiill, shooooot
        for term in lists.words:
            if len(term) >= 4 and _squeeze(term) == squeezed:
                return lists.words[term], "fuzzy"
    if config.fuzzy and len(word) >= 4:
        for term in lists.fuzzy_terms:
            if _edit1(word, term):
                return lists.words[term], "fuzzy"
    return None


@dataclass(slots=True)
class _Piece:
    readings: tuple[str, ...]
    source: str  # the whitespace token it came from, as written
    token: int
    allowed: bool = False


def _pieces(text: str) -> list[_Piece]:
    pieces = []
    for t, token in enumerate(text.split()):
        norm = _TRIM.sub("", _normalise(token))
        for part in _PART.findall(norm):
            pieces.append(_Piece(_readings(part), token, t))
    return pieces


def _mark_allowed(pieces: list[_Piece], lists: _Lists) -> None:
    for phrase in lists.allow_phrases:
        n = len(phrase)
        for start in range(len(pieces) - n + 1):
            window = pieces[start:start + n]
            if all(word in p.readings or word in map(_lemma, p.readings) for word, p in zip(phrase, window)):
                for p in window:
                    p.allowed = True


def _first(pieces: list[_Piece], lists: _Lists, config: GuardConfig) -> Iterator[TextMatch]:
    # Every word on its own.
    for p in pieces:
        if p.allowed:
            continue
        hit = next(filter(None, (_match_word(w, lists, config, exact_only=True) for w in p.readings)), None)
        hit = hit or next(filter(None, (_match_word(w, lists, config) for w in p.readings)), None)
        if hit:
            yield TextMatch(hit[0], p.source, hit[1])
    # Blocked phrases, on lemmas.
    for phrase, term in lists.phrases.items():
        n = len(phrase)
        for start in range(len(pieces) - n + 1):
            window = pieces[start:start + n]
            if not all(p.allowed for p in window) and all(
                    any(_lemma(r) == word or r == word for r in p.readings) for word, p in zip(phrase, window)):
                yield TextMatch(term, " ".join(dict.fromkeys(p.source for p in window)), "phrase")
    # A whitespace token whose pieces were split by punctuation: s.h.o.o.t, k-i-l-l.
    by_token: dict[int, list[_Piece]] = {}
    for p in pieces:
        by_token.setdefault(p.token, []).append(p)
    for group in by_token.values():
        if len(group) > 1 and not all(p.allowed for p in group):
            yield from _joined(group, lists, config)
    # Runs of single letters across whitespace: s h o o t.
    run: list[_Piece] = []
    for p in [*pieces, None]:
        if p is not None and len(p.readings) == 1 and len(p.readings[0]) == 1 and not p.allowed:
            run.append(p)
            continue
        for i in range(len(run)):
            for j in range(i + 3, min(len(run), i + MAX_RUN) + 1):
                word = "".join(q.readings[0] for q in run[i:j])
                if hit := _match_word(word, lists, config, exact_only=True):
                    yield TextMatch(hit[0], " ".join(dict.fromkeys(q.source for q in run[i:j])), "joined")
        run = []
    # Two neighbouring pieces of which one is no word: sh oot, mur der is left alone.
    for a, b in zip(pieces, pieces[1:]):
        if a.allowed or b.allowed:
            continue
        for ra, rb in product(a.readings, b.readings):
            if (_known(ra) and _known(rb)) or len(ra + rb) < 4:
                continue
            if hit := _match_word(ra + rb, lists, config, exact_only=True):
                yield TextMatch(hit[0], " ".join(dict.fromkeys((a.source, b.source))), "joined")


def _joined(group: list[_Piece], lists: _Lists, config: GuardConfig) -> Iterator[TextMatch]:
    options = [p.readings for p in group if p.readings]
    if not options:
        return
    combos = product(*options) if len(group) <= 8 else [tuple(o[0] for o in options)]
    for combo in combos:
        word = "".join(combo)
        if hit := _match_word(word, lists, config):
            yield TextMatch(hit[0], group[0].source, "joined")
            return


def scan_text(text: str, config: GuardConfig = GuardConfig()) -> list[TextMatch]:
    """Every blocked term the text names (empty when it is clean or the guard is off)."""
    if not config.enabled or not text:
        return []
    lists = _lists(config.blocklist, config.allowlist)
    pieces = _pieces(text)
    _mark_allowed(pieces, lists)
    seen, out = set(), []
    for match in _first(pieces, lists, config):
        if (match.term, match.found) not in seen:
            seen.add((match.term, match.found))
            out.append(match)
    return out


def check_text(text: str, field: str = "text", config: GuardConfig = GuardConfig()) -> str:
    """``text`` unchanged when clean; else GuardError naming ``field`` and the first term.
    Captions and prompts call this before they are used."""
    matches = scan_text(text, config)
    if matches:
        raise GuardError(field, matches[0].term, matches[0].found)
    return text


def text_fields(value: Any, path: str = "") -> Iterator[tuple[str, str]]:
    """(dotted path, text) of every string inside a model, mapping or sequence:
    ``task.instruction``, ``cameras[1].name``."""
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    if isinstance(value, str):
        yield path or "(text)", value
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from text_fields(item, f"{path}.{key}" if path else str(key))
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            yield from text_fields(item, f"{path}[{i}]")


def scan_fields(value: Any, config: GuardConfig = GuardConfig()) -> list[tuple[str, TextMatch]]:
    """(field, match) for every blocked term in every text field of ``value``."""
    return [(field, m) for field, text in text_fields(value) for m in scan_text(text, config)]


def check_fields(value: Any, config: GuardConfig = GuardConfig()) -> None:
    """GuardError for the first blocked term in any text field of ``value`` (e.g. a manifest)."""
    for field, match in scan_fields(value, config):
        raise GuardError(field, match.term, match.found)
