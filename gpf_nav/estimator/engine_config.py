"""The estimator engine's settings: :class:`EngineConfig`, what the node's parameters give it, read by the
engine and each of its roles; and :data:`NS`, the unit of its stamps.

The defaults here are the node's (the parameter schema, :mod:`gpf_nav.estimator.params`, takes them from
:class:`EngineConfig`) but for two, whose node values are the constants :data:`NODE_MAX_MEASUREMENT_RATE`
and :data:`NODE_FAULT_ACTION`: an engine driven by a program rather than by a node (offline, on a simulated
clock) runs every input it is given and only reports an integrity fault unless told otherwise."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

NS = 1_000_000_000
"""Nanoseconds per second: stamps are integer nanoseconds of ROS time."""
NODE_MAX_MEASUREMENT_RATE = 1000.0
"""The node's ``max_measurement_rate``, messages per second of its steady clock: it keeps a flood of
messages from starving the node. :class:`EngineConfig`'s is 0 (unlimited): an engine fed faster than real
time, or on a clock that stands still, would otherwise drop inputs by the speed of the machine."""
NODE_FAULT_ACTION = "measurements"
"""The node's ``integrity_fault_action``: a persistent integrity FAULT re-initialises from the next
measurements (:mod:`gpf_nav.estimator.integrity_watch`). :class:`EngineConfig`'s is ``"none"``."""


@dataclass
class EngineConfig:
    """Engine settings (node parameters; units in the field comments)."""

    max_future: float = 1.0                 # s, refuse stamps further ahead of the node clock
    imu_timeout: float = 1.0                # s, an IMU sample older than this is not used
    init_window: int = 10                   # measurements buffered for the batch initialisation
    initial_state: np.ndarray | None = None  # (n,) m, m/s; None: not given
    initial_std: np.ndarray = field(default_factory=lambda: np.array([1e3, 1e3, 1e3, 1.0, 1.0, 1.0]))
    initial_stamp: float = -1.0             # s of ROS time; < 0: the first measurement's stamp
    max_measurement_rate: float = 0.0       # messages per second (steady clock); <= 0: unlimited (the node's: NODE_MAX_MEASUREMENT_RATE)
    max_extrapolation: float = 300.0        # s, predictions are not published further than this
    reinit_inflation: float = 4.0           # covariance factor when re-initialising after a failure
    reinit_hold: float = 10.0               # s (steady clock) the ERROR level is held after it
    monitor: dict | None = field(default_factory=dict)  # CostateMonitor keyword arguments; None: disabled
    monitor_hold: float = 5.0               # s (steady clock) a monitor WARN/FAULT stays reported; < 0: until reset
    consistency: dict | None = field(default_factory=dict)  # ConsistencyMonitor keyword arguments; None: disabled
    history_length: float = 10.0            # s, late measurements within this are fused at their stamp; 0: none
    reapply_budget: float = 0.5             # s of lateness re-applied per s of filter time (ReapplyBudget); 0: unlimited
    gates: dict = field(default_factory=dict)  # stream -> chi-square probability of its innovation gate; 0: off
    gate_limit: int = 5                     # after this many gate refusals in a row the next one is used
    fault_action: str = "none"              # integrity_watch.FAULT_ACTIONS: re-initialise after a persistent FAULT (the node's: NODE_FAULT_ACTION)
    fault_updates: int = 30                 # integrity FAULT updates in a row that make it persistent
