"""Filters behind one interface: the GPF, the bootstrap PF (SPF), EKF, UKF and EnKF."""
from gpf_nav.filters.interface import Filter
from gpf_nav.filters.biased import SensorBiasFilter
from gpf_nav.filters.compensated import CompensatedEKF
from gpf_nav.filters.ensemble import EnsembleKF
from gpf_nav.filters.gpf import GeometricProjectionPF
from gpf_nav.filters.kalman import ExtendedKF, UnscentedKF
from gpf_nav.filters.multiple_model import MultipleModelGPF
from gpf_nav.filters.particle import BootstrapPF, ParticleFilter

__all__ = ["Filter", "SensorBiasFilter", "ParticleFilter", "BootstrapPF", "GeometricProjectionPF", "ExtendedKF",
           "UnscentedKF", "EnsembleKF", "CompensatedEKF", "MultipleModelGPF"]
