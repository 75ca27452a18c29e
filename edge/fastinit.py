"""A faster ``__init__`` for frozen dataclasses made every frame."""

from __future__ import annotations

import dataclasses

__all__ = ["one_dict_init"]


#: the default that the generated ``__init__`` gives a field with a default factory (its signature shows it as
#: ``<factory>``); the factory is called when the argument is this object
_HAS_FACTORY = getattr(dataclasses, "_HAS_DEFAULT_FACTORY", None)


def one_dict_init(cls):
    """The frozen dataclass ``cls`` with an ``__init__`` that sets the instance's ``__dict__`` in one call: the same
    parameters and defaults and the same attributes in field order as the generated one, which calls
    ``object.__setattr__`` once per field (for records made every frame). A field with a default factory gets a
    new value from it when its argument is left out, as with the generated one."""
    fields = dataclasses.fields(cls)
    if not cls.__dataclass_params__.frozen or hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__name__}: a frozen dataclass without __post_init__ is needed")
    glb = {"__set": object.__setattr__, "__has_factory": _HAS_FACTORY}
    params = []
    values = []
    for f in fields:
        if not f.init or f.kw_only or (f.default_factory is not dataclasses.MISSING and _HAS_FACTORY is None):
            raise TypeError(f"{cls.__name__}.{f.name}: positional init fields are needed")
        if f.default_factory is not dataclasses.MISSING:
            glb[f"__factory_{f.name}"] = f.default_factory
            params.append(f"{f.name}=__has_factory")
            values.append(f"__factory_{f.name}() if {f.name} is __has_factory else {f.name}")
        elif f.default is dataclasses.MISSING:
            params.append(f.name)
            values.append(f.name)
        else:
            glb[f"__default_{f.name}"] = f.default
            params.append(f"{f.name}=__default_{f.name}")
            values.append(f.name)
    items = ", ".join(f"{f.name!r}: {v}" for f, v in zip(fields, values))
    ns: dict = {}
    exec(f"def __init__(self, {', '.join(params)}):\n    __set(self, '__dict__', {{{items}}})\n", glb, ns)
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    init.__annotations__ = dict(cls.__init__.__annotations__)
    cls.__init__ = init
    return cls
