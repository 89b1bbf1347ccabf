"""A typo in a number word is refused, never read as the design's default count.

"put eigth dots around the cake" once piped the default ring of 12. Generated typos (a letter
dropped, doubled, swapped with the next, or replaced by its keyboard neighbour) of every number
word from two to ninety, in sentences of both families, must each be refused and name the word.
"""

from __future__ import annotations

import random

import pytest

from keymps.designs.grammar import UnreadableInstruction, read_instruction
from keymps.designs.words import NEAR_NUMBER_WORDS, NUMBER_WORDS, ONES, TENS, misspelled_number

NEIGHBOURS = {
    "a": "qs", "e": "wr", "i": "uo", "o": "ip", "u": "yi", "n": "bm", "t": "ry", "r": "et",
    "s": "ad", "v": "cb", "w": "qe", "f": "dg", "g": "fh", "h": "gj", "x": "zc", "l": "k",
    "y": "tu", "z": "x", "d": "sf",
}  # fmt: skip
TEMPLATES = (
    "put {} dots around the cake",
    "pipe {} little rosettes around the edge",
    "cut it into {} equal slices",
    "cut the loaf into {} pieces",
    "ice {} rings on the cake",
)


def typos(word: str, rng: random.Random) -> set[str]:
    found = set()
    for i in range(len(word)):
        found.add(word[:i] + word[i + 1 :])  # dropped
        found.add(word[:i] + word[i] + word[i:])  # doubled
        if i + 1 < len(word):
            found.add(word[:i] + word[i + 1] + word[i] + word[i + 2 :])  # swapped
        for near in NEIGHBOURS.get(word[i], ""):
            found.add(word[:i] + near + word[i + 1 :])
    found -= set(NUMBER_WORDS) | NEAR_NUMBER_WORDS
    return {typo for typo in found if len(typo) >= 4 and rng.random() < 0.5}


def test_generated_typos_of_number_words_are_refused() -> None:
    rng = random.Random(7)
    words = [w for w in (*ONES[2:], *TENS) if len(w) >= 4]
    cases = [(template, typo, word) for word in words for typo in typos(word, rng)
             for template in rng.sample(TEMPLATES, 2)]  # fmt: skip
    assert len(cases) > 400
    read, refused = [], 0
    for template, typo, _ in cases:
        sentence = template.format(typo)
        try:
            intent = read_instruction(sentence)
        except UnreadableInstruction as error:
            refused += 1
            assert repr(typo) in str(error) or "understood" in str(error), str(error)
        else:
            read.append((sentence, intent.count))
    rate = refused / len(cases)
    # Left read: typos of four-letter words by one substituted letter ('give', 'gour'), under
    # difflib's 0.8 like real words near them ('fine dots' must still read); docs/tasks.md.
    assert rate >= 0.95, (rate, read[:10])
    assert all(len(sentence.split()[1]) == 4 for sentence, _ in read if " dots " in sentence)


@pytest.mark.parametrize("sentence", [f"put {w} dots around the cake" for w in ("eight", "ninety")]
                         + ["cut it into 8 even slices", "cut it into seventy five pieces",
                            "put 12 tiny dots around the cake", "cut it into 6 pieces for our guests"])  # fmt: skip
def test_numbers_and_the_words_near_them_still_read(sentence: str) -> None:
    assert read_instruction(sentence).count is not None


def test_the_message_names_the_word_and_the_number_it_resembles() -> None:
    with pytest.raises(UnreadableInstruction) as caught:
        read_instruction("put eigth dots around the cake")
    message = str(caught.value)
    assert "'eigth'" in message and "did you mean 'eight'?" in message
    assert "never guesses a count" in message and "\n" not in message


@pytest.mark.parametrize(
    ("word", "expected"),
    [("eigth", "eight"), ("fiften", "fifteen"), ("sevn", "seven"), ("ninty", "ninety"),
     ("tenn", "ten"), ("even", None), ("for", None), ("then", None), ("cake", None),
     ("eight", None)],
)  # fmt: skip
def test_misspelled_number(word: str, expected: str | None) -> None:
    assert misspelled_number(word) == expected
