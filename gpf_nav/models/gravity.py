"""The Moon's gravity field beyond the point mass: zonal and low-degree spherical harmonics.

A :class:`GravityField` is the perturbation ``a_p(r, t)`` that a non-spherical Moon adds to the central
term ``-mu r / |r|^3``; the lunar model (:class:`~gpf_nav.models.lunar.LunarDescentModel`) and the
simulator's truth (:mod:`gpf_nav.sim.scenario`) add it to their flows. The coefficients are given in
the Moon-fixed (principal-axis) frame, whose z axis is the inertial frame's (the pole) and which turns
about it at ``rotation_rate``, its x axis the inertial x axis at the time ``epoch``; a zonal field does
not depend on that angle, so its flow does not depend on ``t``.

The acceleration is the Cunningham recursion of the unnormalised solid harmonics in Cartesian
coordinates, compiled (:mod:`gpf_nav.kernels.harmonics`); :meth:`GravityField.potential`, the textbook
sum over Legendre functions, is its independent check.

Published field (:data:`FIELDS`): the lunar gravity field of the JPL planetary and lunar ephemeris
DE430 through degree 4, unnormalised, reference radius 1738.0 km (Folkner, Williams, Boggs, Park and
Kuchynka, *The Planetary and Lunar Ephemerides DE430 and DE431*, IPN Progress Report 42-196, 2014,
the table of lunar gravity coefficients). The Moon's J2 is ``2.0322e-4``: at 100 km altitude it adds
about ``4.6e-4 m/s^2`` to the central ``1.5 m/s^2``, a force 300 times smaller than the paper's 9 %
gravity mismatch.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import lpmv

from gpf_nav.kernels import harmonics

FIELD_RADIUS = 1.738e6
"""Reference radius of the DE430 lunar gravity field, m."""
MOON_ROTATION_RATE = 2.6617e-6
"""The Moon's mean rotation rate, rad/s (IAU WGCCRE 2015: 13.17635815 deg/day)."""

DE430_ZONAL = {2: 2.0321568464952570e-4, 3: 8.4597026974594570e-6, 4: -9.7044138365700000e-6}
"""``J_n`` of DE430's lunar field (``C_n0 = -J_n``), unnormalised."""
DE430_TESSERAL = {
    (2, 2): (2.2382740590560020e-5, 0.0),
    (3, 1): (2.8480741195592860e-5, 5.8915551555318640e-6),
    (3, 2): (4.8449420619770600e-6, 1.6844743962783900e-6),
    (3, 3): (1.6756178134114570e-6, -2.4742714379805760e-7),
    (4, 1): (-5.7048697319733210e-6, 1.5789202789245720e-6),
    (4, 2): (-1.5912271792977430e-6, -1.5153915796731720e-6),
    (4, 3): (-8.0678881596778210e-8, -8.0349266627431070e-7),
    (4, 4): (-1.2692158612216040e-7, 8.2964257754075220e-8),
}
"""``(C_nm, S_nm)`` of DE430's lunar field for ``m >= 1``, unnormalised."""


@dataclass(frozen=True)
class GravityField:
    """Spherical-harmonic perturbation of the central gravity, through degree ``degree``.

    Attributes:
        gm: gravitational parameter the harmonics scale, m^3/s^2.
        radius: reference radius of the coefficients, m.
        C, S: ``(degree + 1, degree + 1)`` unnormalised coefficients ``C_nm``, ``S_nm`` (rows ``n``,
            columns ``m``); degrees 0 and 1 are ignored (the central term is the model's own).
        rotation_rate: the Moon-fixed frame's rotation about the inertial z axis, rad/s.
        epoch: the time at which the Moon-fixed frame's x axis is the inertial x axis, s (the time scale
            of the ``t`` the field is called with).
        name: the field's name (:data:`FIELDS`).
    """

    gm: float
    radius: float
    C: np.ndarray
    S: np.ndarray
    rotation_rate: float = MOON_ROTATION_RATE
    epoch: float = 0.0
    name: str = ""
    degree: int = field(init=False)
    zonal: bool = field(init=False)

    def __post_init__(self):
        C, S = (np.array(a, dtype=float) for a in (self.C, self.S))
        if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape != S.shape or C.shape[0] < 3:
            raise ValueError(f"C and S must be square, of the same shape and at least degree 2; got "
                             f"{C.shape}, {S.shape}")
        if not (np.isfinite(C).all() and np.isfinite(S).all()):
            raise ValueError("gravity coefficients must be finite")
        for array in (C, S):
            array.flags.writeable = False
        object.__setattr__(self, "C", C)
        object.__setattr__(self, "S", S)
        object.__setattr__(self, "degree", C.shape[0] - 1)
        object.__setattr__(self, "zonal", not (np.any(C[2:, 1:]) or np.any(S[2:, 1:])))

    def acceleration(self, r: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Perturbing acceleration ``(3, N)`` at inertial positions ``r`` ``(3, N)`` at time ``t``, m/s^2."""
        r = np.asarray(r, dtype=float)
        if self.zonal:
            return self._body_acceleration(r)
        c, s = self._rotation(t)
        body = np.stack([c * r[0] + s * r[1], -s * r[0] + c * r[1], r[2]])
        a = self._body_acceleration(body)
        return np.stack([c * a[0] - s * a[1], s * a[0] + c * a[1], a[2]])

    def _rotation(self, t: float) -> tuple[float, float]:
        angle = self.rotation_rate * (float(t) - self.epoch)
        return math.cos(angle), math.sin(angle)

    def _body_acceleration(self, r: np.ndarray) -> np.ndarray:
        """The harmonics' acceleration ``(3, N)`` at Moon-fixed positions ``r`` ``(3, N)``
        (:func:`gpf_nav.kernels.harmonics.acceleration`)."""
        out = np.empty((3, r.shape[1]))
        harmonics.acceleration(np.ascontiguousarray(r), self.C, self.S, self.radius, self.gm, out)
        return out

    def potential(self, r: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Perturbing potential ``(N,)`` at inertial positions ``r`` ``(3, N)``, m^2/s^2 (its gradient is
        :meth:`acceleration`; the tests check one against the other)."""
        r = np.asarray(r, dtype=float)
        c, s = self._rotation(t)
        x, y, z = c * r[0] + s * r[1], -s * r[0] + c * r[1], r[2]
        radius = np.sqrt(x * x + y * y + z * z)
        sin_lat = z / radius
        longitude = np.arctan2(y, x)
        out = np.zeros(r.shape[1])
        for n in range(2, self.degree + 1):
            for m in range(n + 1):
                legendre = _associated_legendre(n, m, sin_lat)
                out += ((self.radius / radius) ** n * legendre
                        * (self.C[n, m] * np.cos(m * longitude) + self.S[n, m] * np.sin(m * longitude)))
        return self.gm / radius * out


def _associated_legendre(n: int, m: int, u: np.ndarray) -> np.ndarray:
    """Unnormalised ``P_nm(u)`` without the Condon-Shortley phase (the geodesy convention)."""
    return (-1.0) ** m * lpmv(m, n, u)


def zonal_field(gm: float, zonal: dict[int, float], radius: float = FIELD_RADIUS, name: str = "") -> GravityField:
    """A field of zonal terms only, ``{n: J_n}``."""
    degree = max(zonal)
    C = np.zeros((degree + 1, degree + 1))
    for n, j in zonal.items():
        C[n, 0] = -j
    return GravityField(gm, radius, C, np.zeros_like(C), name=name)


def harmonic_field(gm: float, degree: int, epoch: float = 0.0,
                   rotation_rate: float = MOON_ROTATION_RATE) -> GravityField:
    """DE430's lunar field through ``degree`` (2 to 4), zonal and tesseral terms."""
    if not 2 <= degree <= 4:
        raise ValueError(f"the DE430 field is given through degree 4; got {degree}")
    C = np.zeros((degree + 1, degree + 1))
    S = np.zeros_like(C)
    for n, j in DE430_ZONAL.items():
        if n <= degree:
            C[n, 0] = -j
    for (n, m), (c, s) in DE430_TESSERAL.items():
        if n <= degree:
            C[n, m], S[n, m] = c, s
    return GravityField(gm, FIELD_RADIUS, C, S, rotation_rate, epoch, name=f"degree{degree}")


FIELDS = ("point", "j2", "zonal", "degree4")
"""Names of the fields :func:`make_field` builds: the point mass (no perturbation), DE430's J2 alone,
its zonal terms J2-J4, and its full field through degree 4."""


def make_field(name: str, gm: float, epoch: float = 0.0) -> GravityField | None:
    """The field ``name`` (:data:`FIELDS`) for the gravitational parameter ``gm`` (``epoch``: the Moon-fixed
    frame's, :class:`GravityField`); None for the point mass."""
    if name == "point":
        return None
    if name == "j2":
        return zonal_field(gm, {2: DE430_ZONAL[2]}, name="j2")
    if name == "zonal":
        return zonal_field(gm, DE430_ZONAL, name="zonal")
    if name == "degree4":
        return harmonic_field(gm, 4, epoch)
    raise ValueError(f"unknown gravity field {name!r}; known: {', '.join(FIELDS)}")
