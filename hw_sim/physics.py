"""Physics model choices of the simulator: one record per scenario, the ``[physics]`` table.

Every field is a documented modelling choice (its basis in the field's comment). The defaults are the
more physical choice; ``preset = "v1"`` restores the model every figure before the evaluation corpus was
measured on (white glint, near face 70 % of the RCS, narrow elevation beams, no road bounce, an ideal
receiver), so tests that guard figures measured on it keep their instrument.

Schema::

    [physics]
    preset = "v1"        # optional: start from a named preset, then apply the keys below
    # ... one key per field of Physics
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Physics:
    """Modelling choices of the simulated world and board (see module docstring)."""

    #: name of the preset the record started from ("" = the defaults)
    preset: str = ""

    # --- surveillance site (Distance2Go, hw_sim.events / hw_sim.pedestrian) ---
    #: pedestrian micro-Doppler model: "boulic" = limb kinematics of Boulic, Magnenat-Thalmann & Thalmann
    #: 1990 (The Visual Computer 6:344-358; joint trajectories fitted to measured gait as functions of the
    #: relative velocity, the model of Chen, The Micro-Doppler Effect in Radar, 2011, ch. 5) with ellipsoid
    #: segments; "sinusoid" = eight point scatterers swinging sinusoidally (hw_sim.pedestrian, v1)
    gait: str = "boulic"
    #: vehicle scatterers on flat panels (bumpers, doors, tailgate) have a flat plate's aspect lobe
    #: cos^2 * sinc^2 (Knott, Shaeffer & Tuley, Radar Cross Section, 2nd ed. 2004, ch. 6) above a diffuse
    #: floor; false = every scatterer isotropic (v1)
    vehicle_lobes: bool = True
    #: vehicle wheels rotate: rim and tread scatterers with the rim's tangential velocity, so the wheel's
    #: micro-Doppler spans 0..2v (Chen 2011, ch. 4); false = static wheel-arch points only (v1)
    wheels: bool = True
    #: static surroundings of the surveillance site: "urban" = the v1 objects plus parked cars (several
    #: scatterers each), a fence with posts every 2 m, a building wall and trees/bushes whose leaves sway in
    #: the wind (Billingsley, Low-Angle Radar Land Clutter, 2002, ch. 6); "v1" = the seven point objects only
    site_clutter: str = "urban"


#: named presets: field -> value (fields not listed keep their defaults)
PRESETS: dict[str, dict[str, Any]] = {
    "v1": {"gait": "sinusoid", "vehicle_lobes": False, "wheels": False, "site_clutter": "v1"},
}


#: string fields with a closed set of values
CHOICES: dict[str, tuple[str, ...]] = {
    "gait": ("boulic", "sinusoid"),
    "site_clutter": ("urban", "v1"),
}


class PhysicsError(ValueError):
    """A ``[physics]`` table names an unknown key or preset, or a value of the wrong type."""


def parse_physics(table: dict[str, Any] | None, where: str = "physics.") -> Physics:
    """The :class:`Physics` of a scenario's ``[physics]`` table (``None`` or empty: the defaults)."""
    table = dict(table or {})
    fields = {f.name: f for f in dataclasses.fields(Physics)}
    values: dict[str, Any] = {}
    preset = table.pop("preset", "")
    if preset:
        if preset not in PRESETS:
            raise PhysicsError(f"{where}preset must be one of {sorted(PRESETS)}, got {preset!r}")
        values.update(PRESETS[preset])
        values["preset"] = preset
    for key, val in table.items():
        if key not in fields:
            raise PhysicsError(f"{where}{key}: unknown key; known: {sorted(k for k in fields if k != 'preset')}")
        default = fields[key].default
        if isinstance(default, bool):
            ok = isinstance(val, bool)
        elif isinstance(default, (int, float)):
            ok = isinstance(val, (int, float)) and not isinstance(val, bool)
            val = type(default)(val) if ok and isinstance(default, float) else val
        elif isinstance(default, str):
            ok = isinstance(val, str)
        elif isinstance(default, tuple):
            ok = isinstance(val, (list, tuple))
            val = tuple(val) if ok else val
        else:
            ok = True
        if not ok:
            raise PhysicsError(f"{where}{key} must be like {default!r}, got {val!r}")
        values[key] = val
    for key, allowed in CHOICES.items():
        if key in values and values[key] not in allowed:
            raise PhysicsError(f"{where}{key} must be one of {list(allowed)}, got {values[key]!r}")
    try:
        return Physics(**values)
    except (TypeError, ValueError) as exc:
        raise PhysicsError(f"{where}{exc}") from None
