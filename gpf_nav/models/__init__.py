"""State-space models: the batched interface and the shipped linear-Gaussian and lunar-descent models."""
from gpf_nav.models.state_space import StateSpaceModel, wrap_angle
from gpf_nav.models.linear import LinearGaussianModel
from gpf_nav.models.lunar import MOON_RADIUS, MU_MOON, LunarDescentModel

__all__ = ["StateSpaceModel", "wrap_angle", "LinearGaussianModel", "LunarDescentModel", "MU_MOON",
           "MOON_RADIUS"]
