"""Letters the Hershey fonts lack but German, the Nordic languages and their neighbours need
(issue 26): ß, æ, ø, Æ, Ø, œ, ð, þ, ł, đ ... drawn, barred or joined from the font's own
letters, and Latin Extended-A's accented letters (č, ő, ą, ż ...) from more accents."""
from __future__ import annotations

import unicodedata

import pytest

from bulgekit.errors import InputError
from bulgekit.bulge.strokes import text_strokes

SIZE = 6.0                           # capital height, mm
NEW = "ßẞæÆøØœŒðÐþÞłŁđĐħĦŧŦıĳĲ"


def box(strokes):
    us = [u for s in strokes for u, _ in s.points]
    vs = [v for s in strokes for _, v in s.points]
    return min(us), max(us), min(vs), max(vs)


def advance(text):
    """Where the next letter starts: the u of a following "I"'s stem, minus the same after ""."""
    return box(text_strokes(text + "I", SIZE))[1] - box(text_strokes("I", SIZE))[1]


@pytest.mark.parametrize("font", ["futural", "timesr", "rowmans"])
def test_german_and_nordic_text_is_drawn(font):
    for text in ("Grüße aus Straßburg", "Blåbærsyltetøy", "ÆRØ ÅLESUND", "Þórður Ðóra", "Łódź",
                 "Œuvre", "Příliš žluťoučký kůň", "Őrség ĳs", "ĄĘŻ ąęż"):
        strokes = text_strokes(text, SIZE, font=font)
        assert strokes
        for s in strokes:                          # nothing flies off the line
            assert all(-0.5 * SIZE < v < 1.5 * SIZE for _, v in s.points), (font, text, s.source)


@pytest.mark.parametrize("ch", NEW)
def test_each_new_letter_sits_in_its_own_space(ch):
    strokes = text_strokes(ch, SIZE)
    assert strokes and all(s.source.endswith(repr(ch)) for s in strokes)
    lo, hi, bottom, top = box(strokes)
    adv = advance(ch)
    assert 0.3 * SIZE < adv < 1.6 * SIZE
    assert -0.2 < lo and hi < adv + 0.2                  # inside its advance: no overlap with neighbours
    assert top <= SIZE * 1.1                             # no taller than a capital (+ ð's hook)
    # only þ and j descend; the slash of ø and Ø pokes 1/21 of a capital out below
    assert bottom >= (-0.4 * SIZE if ch in "þĳ" else -1.1 * SIZE / 21 if ch in "øØ" else -1e-9)
    if ch.isupper():
        assert top > 0.95 * SIZE


@pytest.mark.parametrize("ch, base", [("ø", "o"), ("Ø", "O"), ("ł", "l"), ("Ł", "L"), ("đ", "d"),
                                      ("Đ", "D"), ("ħ", "h"), ("Ħ", "H"), ("ŧ", "t"), ("Ŧ", "T")])
def test_a_barred_letter_is_its_letter_and_one_stroke_across_it(ch, base):
    got, plain = text_strokes(ch, SIZE), text_strokes(base, SIZE)
    assert [s.points for s in got[:-1]] == [s.points for s in plain]
    (a, b) = got[-1].points
    lo, hi, bottom, top = box(plain)
    assert a[0] < (lo + hi) / 2 < b[0] or lo - 1 < a[0] < b[0] < hi + 1   # across, not beside
    assert bottom - 0.5 <= min(a[1], b[1]) and max(a[1], b[1]) <= top + 0.5
    if ch in "øØ":                                  # a slash: lower left to upper right
        assert a[0] < b[0] and a[1] < b[1] and b[1] - a[1] > 0.6 * (top - bottom)


@pytest.mark.parametrize("ch, pair", [("æ", "ae"), ("œ", "oe")])
def test_a_ligature_is_its_two_letters_touching(ch, pair):
    got = text_strokes(ch, SIZE)
    first, second = text_strokes(pair[0], SIZE), text_strokes(pair[1], SIZE)
    assert [s.points for s in got[:len(first)]] == [s.points for s in first]
    rest = got[len(first):]
    assert len(rest) == len(second)
    # the second letter moved left onto the first's right edge: narrower than the two apart
    assert box(first)[1] == pytest.approx(box(rest)[0], abs=1e-9)
    assert advance(ch) < advance(pair) - 0.5


def test_the_sharp_s_is_one_stroke_from_the_baseline_over_the_top_and_back():
    (s,) = text_strokes("ß", SIZE)
    start, end = s.points[0], s.points[-1]
    assert start[1] == pytest.approx(0) and end[1] == pytest.approx(0)     # both ends on the baseline
    assert max(v for _, v in s.points) == pytest.approx(SIZE)               # as tall as a capital
    right = max(s.points)                                                   # the lower bowl is the wider
    assert right[0] > start[0] + 0.5 * SIZE and right[1] < SIZE / 2
    upper = max(p[0] for p in s.points if p[1] > SIZE / 2)
    assert upper < right[0]


@pytest.mark.parametrize("ch", "ĀāĂăĄąĆćĈĉĊċČčĎďĒēĔĕĖėĘęĚěĜĝĞğĠġĢģĤĥĨĩĪīĬĭĮįİĴĵĶķĹĺĻļĽľŃńŅņŇňŌōŎŏŐőŔŕŖŗŘř"
                                "ŚśŜŝŞşŠšŢţŤťŨũŪūŬŭŮůŰűŲųŴŵŶŷŸŹźŻżŽž")
def test_latin_extended_a_accented_letters_are_their_letter_and_accents(ch):
    base = unicodedata.normalize("NFD", ch)[0]
    got, plain = text_strokes(ch, SIZE), text_strokes(base, SIZE)
    keep = [s.points for s in plain]
    if base in "ij":                                # the dot gives way to the accent
        keep = keep[1:]
    assert [s.points for s in got[:len(keep)]] == keep
    assert len(got) > len(keep)


def test_still_missing_is_named():
    with pytest.raises(InputError, match=r"character 'ŋ' \(position 3\)"):
        text_strokes("æøŋ", SIZE)
