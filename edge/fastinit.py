"""A faster ``__init__`` for frozen dataclasses made every frame."""

from __future__ import annotations

import dataclasses

__all__ = ["one_dict_init"]


def one_dict_init(cls):
    """The frozen dataclass ``cls`` with an ``__init__`` that sets the instance's ``__dict__`` in one call: the same
    parameters and defaults and the same attributes in field order as the generated one, which calls
    ``object.__setattr__`` once per field (for records made every frame)."""
    fields = dataclasses.fields(cls)
    if not cls.__dataclass_params__.frozen or hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__name__}: a frozen dataclass without __post_init__ is needed")
    glb = {"__set": object.__setattr__}
    params = []
    for f in fields:
        if not f.init or f.default_factory is not dataclasses.MISSING or f.kw_only:
            raise TypeError(f"{cls.__name__}.{f.name}: init fields without a default factory are needed")
        if f.default is dataclasses.MISSING:
            params.append(f.name)
        else:
            glb[f"__default_{f.name}"] = f.default
            params.append(f"{f.name}=__default_{f.name}")
    items = ", ".join(f"{f.name!r}: {f.name}" for f in fields)
    ns: dict = {}
    exec(f"def __init__(self, {', '.join(params)}):\n    __set(self, '__dict__', {{{items}}})\n", glb, ns)
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    init.__annotations__ = dict(cls.__init__.__annotations__)
    cls.__init__ = init
    return cls
