"""The model seam: the protocol every identification method implements, the shell of a model
file that all methods share, and the registry from a file's method name to its estimator and
file codec."""

from diag_plugin.models.protocol import Capabilities, Model, Prediction
from diag_plugin.models.registry import METHODS, Method, get_method
from diag_plugin.models.spec import ModelSpec, Variable

__all__ = [
    "METHODS",
    "Capabilities",
    "Method",
    "Model",
    "ModelSpec",
    "Prediction",
    "Variable",
    "get_method",
]
