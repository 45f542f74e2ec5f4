"""Per-frame time of day and weather (SPEC 3.1): drawn deterministically from (episode seed, step).

A condition is a time of day (morning, noon, evening, night) and weather intensities in
percent (0-100) for sunny, cloudy, rainy, foggy; a second weather is mixed in with
``ConditionParams.combine_probability``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.params import ConditionParams

WEATHERS = ("sunny", "cloudy", "rainy", "foggy")
#: time of day -> (sun elevation deg, sun azimuth deg, sun strength, ambient, sky RGB)
TIMES: dict[str, tuple[float, float, float, float, tuple[float, float, float]]] = {
    "morning": (20.0, 60.0, 0.8, 0.35, (0.62, 0.72, 0.85)),
    "noon": (65.0, 150.0, 1.0, 0.45, (0.45, 0.65, 0.95)),
    "evening": (12.0, 250.0, 0.6, 0.25, (0.85, 0.55, 0.4)),
    "night": (-20.0, 0.0, 0.0, 0.03, (0.02, 0.03, 0.07)),
}


@dataclass(frozen=True)
class Condition:
    """Lighting and weather of one frame."""

    time_of_day: str
    weather: dict[str, int]  # percent per WEATHERS entry

    def meta(self) -> dict:
        return {"time_of_day": self.time_of_day, "weather": dict(self.weather)}

    @property
    def rain(self) -> float:
        return self.weather["rainy"] / 100.0

    @property
    def fog(self) -> float:
        return self.weather["foggy"] / 100.0

    @property
    def cloud(self) -> float:
        return max(self.weather["cloudy"], self.weather["rainy"]) / 100.0


def draw_condition(cp: ConditionParams, seed: int, step: int) -> Condition:
    """The condition of ``step`` of the episode with ``seed`` (pure function)."""
    rng = np.random.default_rng([seed, step, 7919])
    tod = cp.times[int(rng.integers(0, len(cp.times)))]
    w = {k: 0 for k in WEATHERS}
    first = cp.weathers[int(rng.integers(0, len(cp.weathers)))]
    w[first] = int(rng.integers(40, 101))
    if len(cp.weathers) > 1 and rng.uniform() < cp.combine_probability:
        others = [x for x in cp.weathers if x != first]
        w[others[int(rng.integers(0, len(others)))]] = int(rng.integers(20, 81))
    return Condition(tod, w)


def sun_vector(cond: Condition) -> np.ndarray:
    """Unit vector towards the sun (world frame)."""
    el, az = np.deg2rad(TIMES[cond.time_of_day][0]), np.deg2rad(TIMES[cond.time_of_day][1])
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
