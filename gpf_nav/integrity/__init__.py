"""Estimator integrity: is the estimate to be trusted, and where is it not determined?

* :mod:`~gpf_nav.integrity.costate`: the co-state monitor (a model or estimator that disagrees with the
  data), :class:`CostateMonitor`;
* :mod:`~gpf_nav.integrity.consistency`: the consistency monitor on the normalised innovations (a
  covariance that is too small for the errors the data show), :class:`ConsistencyMonitor`;
* :mod:`~gpf_nav.integrity.observability`: the observability report (which directions the data have not
  determined), :class:`ObservabilityTracker`.
"""
from gpf_nav.integrity.costate import LEVELS, CostateMonitor, IntegrityStatus, hotelling_t2, t2_threshold
from gpf_nav.integrity.consistency import ConsistencyMonitor, ConsistencyStatus, innovation_moments
from gpf_nav.integrity.observability import ObservabilityReport, ObservabilityTracker, UNDETERMINED_INFORMATION

__all__ = ["ConsistencyMonitor", "ConsistencyStatus", "innovation_moments", "CostateMonitor", "IntegrityStatus", "hotelling_t2", "t2_threshold", "LEVELS",
           "ObservabilityReport", "ObservabilityTracker", "UNDETERMINED_INFORMATION"]
