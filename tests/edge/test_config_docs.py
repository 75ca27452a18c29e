"""Config docs say what a knob does, in a sentence or two; the runs behind a default live in docs/decisions."""

import dataclasses
import re

import pytest

from edge.config import load_config

#: longest field doc: two sentences of a knob's effect and unit (the longest today is about 270 characters)
MAX_DOC_CHARS = 300
#: what a per-run story looks like: a simulator seed, a scenario or event generator run, a per-seed result list
STORY = re.compile(r"\bseeds? \d|\bhighway4|\bwrong-way-traffic\b|\b(single|multi)-random\b|\bTavanti Tests? \d"
                   r"|\d\.\d+/\d\.\d+/", re.IGNORECASE)


def _fields():
    cfg = load_config(None)
    for name, section in cfg._sections.items():
        for f in dataclasses.fields(section):
            yield f"{name}.{f.name}", f.metadata.get("doc", "")


FIELDS = list(_fields())


def test_every_field_has_a_doc():
    missing = [key for key, doc in FIELDS if not doc.strip()]
    assert not missing, f"fields without a doc: {missing}"


@pytest.mark.parametrize("key,doc", FIELDS, ids=[k for k, _ in FIELDS])
def test_doc_is_short_and_tells_no_run(key, doc):
    assert len(doc) <= MAX_DOC_CHARS, f"{key}: {len(doc)} characters (at most {MAX_DOC_CHARS}: what it does, its unit)"
    story = STORY.search(doc)
    assert story is None, f"{key}: cites a run ({story.group(0)!r}); that belongs in docs/decisions"


def test_story_pattern_catches_what_it_should():
    # the check above is only as good as its pattern: these are the forms the old docs used
    for text in ("(highway4-traffic seed 7001: ...)", "dev seeds 11/12 1.00/0.95", "multi-random 101/102",
                 "wrong-way-traffic seed 1", "Tavanti Test 3's motorcycle"):
        assert STORY.search(text), text
    assert STORY.search("a Hann-windowed peak spreads over +-2 bins") is None
