"""The campaigns' surface-station conditions: the descent tracked from beacons on the rotating Moon.

The station at the Moon's centre is replaced by beacons on the surface (``ScenarioConfig.surface_stations``,
:mod:`gpf_nav.sim.surface_stations`): each measures range and topocentric azimuth and elevation, turns
with the Moon (IAU rate, the Moon-fixed x axis the inertial one at the run's start), and sees the
vehicle only above its horizon; between passes the filters predict. The beacons stand on the ground
track of the default descent (from 0 deg, 0 deg at apolune north-east to 24.4 deg N, 128.0 deg E below
the vehicle at 2400 s, 33 km up: the landing site). What each sees of run 0 (seed 0) of the default
descent (the truth's process noise moves these by a few seconds between runs):

* ``surface-gaps``, one beacon mid-track (26 N, 57 E): 850-1500 s, 27 % of the steps; the filters
  predict from the prior for 850 s, then for 900 s after the pass.
* ``surface-two``, an uprange beacon (10 N, 18 E), 32-766 s, and one at the landing site, 2174-2400 s:
  40 % of the steps, a 1400 s gap between.
"""
from __future__ import annotations

import math

MID_TRACK = (math.radians(26.0), math.radians(57.0), 0.0)
"""Latitude, longitude (rad) and height (m) of ``surface-gaps``'s beacon."""
UPRANGE = (math.radians(10.0), math.radians(18.0), 0.0)
"""The beacon that sees the descent's first 770 s."""
LANDING_SITE = (math.radians(24.4), math.radians(128.0), 0.0)
"""The ground below the default descent's end (2400 s), and its beacon."""
SURFACE = {
    "surface-gaps": ("one surface beacon mid-track (visible 850-1500 s)", {"surface_stations": MID_TRACK}),
    "surface-two": ("two surface beacons, uprange and landing site (32-766 s, 2174-2400 s)",
                    {"surface_stations": UPRANGE + LANDING_SITE}),
}
"""name -> (label, changes of the base scenario), as the stress conditions."""
