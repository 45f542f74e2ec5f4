"""Time of day and weather of a CARLA episode: the world's names (``world.conditions``) as
``carla.WeatherParameters`` keyword arguments.

One time and one weather with an intensity (percent, as the world's frame metadata) are drawn per
episode from the episode's seed; the server then keeps them for the whole drive.
"""
from __future__ import annotations

import numpy as np

#: sun altitude (degrees above the horizon) of each time of day
SUN_ALTITUDE_DEG = {"morning": 15.0, "noon": 70.0, "evening": 3.0, "night": -40.0}


def draw_condition(times: list[str], weathers: list[str], seed: int) -> tuple[str, str, float]:
    """(time, weather, intensity in 30..100 %) of an episode."""
    rng = np.random.default_rng([int(seed), 7])
    return (str(times[int(rng.integers(len(times)))]), str(weathers[int(rng.integers(len(weathers)))]),
            float(np.round(rng.uniform(30.0, 100.0), 1)))


def weather_parameters(time: str, weather: str, intensity: float) -> dict[str, float]:
    """Keyword arguments of ``carla.WeatherParameters`` for a time, a weather and its intensity (%)."""
    k = float(intensity)
    p = {"cloudiness": 10.0, "precipitation": 0.0, "precipitation_deposits": 0.0, "wind_intensity": 10.0,
         "fog_density": 0.0, "wetness": 0.0, "sun_azimuth_angle": 45.0, "sun_altitude_angle": SUN_ALTITUDE_DEG[time]}
    if weather == "cloudy":
        p["cloudiness"] = k
    elif weather == "rainy":
        p.update(cloudiness=max(60.0, k), precipitation=k, precipitation_deposits=k / 2, wetness=k / 2)
    elif weather == "foggy":
        p.update(cloudiness=50.0, fog_density=k)
    return p
