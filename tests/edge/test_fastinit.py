"""edge.fastinit.one_dict_init: the records made every frame construct as their generated dataclass ``__init__``
would: the same signature, the same attributes in field order, defaults, frozen, ``dataclasses.replace``, equality."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from edge.dsp.pairing import Pairs
from edge.fastinit import one_dict_init
from edge.lane.records import Angles, Candidates, Feedback, PairList, Peaks, Spectra
from edge.traffic.monitor import TrafficUpdate
from edge.types import Detections

RECORDS = (Feedback, Spectra, Peaks, PairList, Angles, Candidates, Pairs, TrafficUpdate, Detections)


def _generated(cls):
    """``cls`` as the plain dataclass (its generated ``__init__``)."""
    params = cls.__dataclass_params__
    fields = [(f.name, f.type, dataclasses.field(default=f.default)) if f.default is not dataclasses.MISSING
              else (f.name, f.type, dataclasses.field(default_factory=f.default_factory))
              if f.default_factory is not dataclasses.MISSING else (f.name, f.type) for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass("Ref" + cls.__name__, fields, frozen=True, eq=params.eq)


def _values(cls, n):
    return [np.arange(k + 1.0) if k % 2 else (k, None) for k in range(n)]


@pytest.mark.parametrize("cls", RECORDS)
def test_same_signature_and_attributes(cls):
    ref = _generated(cls)
    got, want = inspect.signature(cls.__init__).parameters, inspect.signature(ref.__init__).parameters
    assert [(p.name, p.kind, p.default) for p in got.values()] == [(p.name, p.kind, p.default) for p in want.values()]
    fields = dataclasses.fields(cls)
    required = [f for f in fields if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    for n in sorted({len(required), len(fields)}):
        vals = _values(cls, n)
        a, b = cls(*vals), ref(*vals)
        assert list(vars(a).items()) == list(vars(b).items())  # (values compared by identity first)
        kw = {f.name: v for f, v in zip(fields, vals)}
        assert list(vars(cls(**kw)).items()) == list(vars(a).items())
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(a, fields[0].name, 1)
        c = dataclasses.replace(a, **{fields[-1].name: "x"})
        assert type(c) is cls and getattr(c, fields[-1].name) == "x"
    with pytest.raises(TypeError):
        cls(*_values(cls, len(fields) + 1))
    with pytest.raises(TypeError):
        cls(*_values(cls, len(required) - 1))


def test_pairs_equality_and_hash_as_generated():
    v = (np.zeros((0, 4)), np.zeros(0), np.zeros(0), np.zeros(0), 1, 2)
    assert Pairs(*v).__eq__.__qualname__.startswith("Pairs")
    p = TrafficUpdate((), (), (), ())
    assert p == TrafficUpdate((), (), (), ()) and hash(p) == hash(TrafficUpdate((), (), (), ()))


def test_refuses_what_it_cannot_reproduce():
    @dataclasses.dataclass
    class NotFrozen:
        a: int

    @dataclasses.dataclass(frozen=True)
    class Post:
        a: int

        def __post_init__(self):
            pass

    @dataclasses.dataclass(frozen=True)
    class KwOnly:
        a: int = dataclasses.field(kw_only=True)

    for cls in (NotFrozen, Post, KwOnly):
        with pytest.raises(TypeError):
            one_dict_init(cls)


def test_a_default_factory_makes_a_new_value_each_time():
    """A field with a default factory (Detections.extra): a new value from the factory when the argument is left
    out, the argument itself when given, as the generated ``__init__`` does."""
    calls = []

    @one_dict_init
    @dataclasses.dataclass(frozen=True)
    class Factory:
        a: int
        b: dict = dataclasses.field(default_factory=lambda: calls.append(1) or {})

    x, y = Factory(1), Factory(2)
    assert x.b == {} and y.b == {} and x.b is not y.b and len(calls) == 2
    given = {"k": 1}
    assert Factory(3, given).b is given and Factory(a=4, b=given).b is given and len(calls) == 2
    assert list(vars(x)) == ["a", "b"]
    d = Detections(*[np.zeros(1, np.float32)] * 6)
    assert d.extra == {} and Detections(*[np.zeros(1, np.float32)] * 6).extra is not d.extra
