"""Filters made of other filters: the state of a :class:`Composite` lives in its members.

A composite declares, rather than forwards, how it answers the interface:

* its lifecycle is its members': its time and initialisation are those of the principal member (the last
  of :attr:`Composite.members`), its recoveries the sum of every member's, its observability the
  principal member's report and every member's trackers;
* each optional capability (:data:`~gpf_nav.filters.interface.CAPABILITIES`) is either its own
  (:attr:`Composite.own_capabilities`: the composite defines the capability's attributes, e.g. a model
  average over the members) or answered by the member :meth:`Composite.delegate` names: the
  capability's attributes (:data:`~gpf_nav.filters.interface.ATTRIBUTES`) then read that member's, and the
  composite has the capability when that member has it.
"""
from __future__ import annotations

from abc import abstractmethod

from gpf_nav.filters.interface import ATTRIBUTES, CAPABILITIES, Filter
from gpf_nav.integrity.observability import ObservabilityReport, ObservabilityTracker
from gpf_nav.models.state_space import StateSpaceModel


class Composite(Filter):
    """Base class of a filter whose state lives in member filters (module docstring).

    It does not run :meth:`Filter.__init__`: the state that sets up (random stream, time, recovery
    memory, observability tracker) is each member's.

    Args:
        model: the user's state-space model (the state :attr:`mean` and :attr:`covariance` are of).
    """

    own_capabilities: frozenset[str] = frozenset()
    """The capabilities the composite answers itself (it defines their attributes)."""

    def __init__(self, model: StateSpaceModel):
        self.model = model

    @property
    @abstractmethod
    def members(self) -> tuple[Filter, ...]:
        """The member filters, the principal one last."""

    def delegate(self, capability: str) -> Filter | None:
        """The member that answers ``capability`` (not one of :attr:`own_capabilities`); None: no member
        does, and its attributes read their absent value."""
        return None

    @property
    def capabilities(self) -> frozenset[str]:
        """:attr:`own_capabilities`, and each capability the member :meth:`delegate` names has."""
        delegated = set()
        for capability in CAPABILITIES:
            member = None if capability in self.own_capabilities else self.delegate(capability)
            if member is not None and capability in member.capabilities:
                delegated.add(capability)
        return self.own_capabilities | delegated

    # --- the lifecycle, from the members -----------------------------------------------------------------
    @property
    def principal(self) -> Filter:
        """The member whose clock and observability report are the composite's."""
        return self.members[-1]

    @property
    def time(self) -> float:
        return self.principal.time

    @property
    def initialized(self) -> bool:
        return self.principal.initialized

    @property
    def recoveries(self) -> int:
        """Re-initialisations of every member."""
        return sum(member.recoveries for member in self.members)

    @property
    def last_recovery_reason(self) -> str | None:
        """Why a member last re-initialised itself (the principal first, then back along
        :attr:`members`), or None."""
        return next((m.last_recovery_reason for m in reversed(self.members) if m.last_recovery_reason), None)

    @property
    def observability(self) -> ObservabilityReport | None:
        """The principal member's report."""
        return self.principal.observability

    def observability_trackers(self) -> tuple[ObservabilityTracker, ...]:
        """Every member's trackers."""
        return tuple(tracker for member in self.members for tracker in member.observability_trackers())


class _Delegated:
    """A capability attribute of :class:`Composite`: the delegate member's, or the absent value of
    :class:`Filter` when no member answers the capability. A non-data descriptor, so that a composite's own
    attribute (an instance attribute or a property of the subclass) takes precedence."""

    def __init__(self, capability: str, name: str):
        self.capability, self.name = capability, name

    def __get__(self, composite: Composite | None, owner: type | None = None):
        if composite is None:
            return self
        member = None if self.capability in composite.own_capabilities else composite.delegate(self.capability)
        if member is None:
            return getattr(super(Composite, composite), self.name)
        return getattr(member, self.name)


def _declare_delegated_attributes() -> None:
    """Give :class:`Composite` every capability attribute of :data:`ATTRIBUTES` as a :class:`_Delegated`."""
    for capability, names in ATTRIBUTES.items():
        for name in names:
            setattr(Composite, name, _Delegated(capability, name))


_declare_delegated_attributes()
