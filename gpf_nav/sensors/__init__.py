"""Measurement models as objects: ``h``, ``H``, ``R``, angular mask and optional bias states (no rclpy).

Every filter updates with any of them, ``filter.update(y, sensor)``; ``filter.update(y)`` uses the
model's own measurement, :class:`ModelSensor`.
"""
from gpf_nav.sensors.sensor import (Bias, Padded, Sensor, gauss_markov_bias, innovation_distance,
                                  random_constant_bias)
from gpf_nav.sensors.bias import BiasedSensor, SensorBiasModel
from gpf_nav.sensors.kinematic import AltitudeSensor, PositionSensor, StateComponentSensor, VelocitySensor
from gpf_nav.sensors.model import ModelSensor
from gpf_nav.sensors.station import StationSensor

__all__ = ["Sensor", "Bias", "Padded", "gauss_markov_bias", "random_constant_bias", "innovation_distance",
           "ModelSensor",
           "PositionSensor", "VelocitySensor", "AltitudeSensor", "StateComponentSensor", "SensorBiasModel",
           "BiasedSensor", "StationSensor"]
