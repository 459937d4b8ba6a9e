"""A face rig as a solve target: bones, custom properties that drivers read, shape keys.

Blender only evaluates the rig (``facecap_addon.rig.rig_eval``); here the rig is a ``RigModel`` (the
bound points as a quadratic function of the controls, fitted from probes: ``probe_rig``) solved by
bounded nonlinear least squares (``solve_nonlinear``), or a ``PoseLibrary`` (a control pose per
semantic shape, columns of the existing solve). ``RigTarget`` carries either through
``solvers.solve`` (``SolveRequest.rig``).
"""

from .fit import fit_model
from .model import RigModel
from .nonlinear import NonlinearResult, iterate_nonlinear, solve_nonlinear
from .poses import PoseLibrary
from .probe import ProbeReport, probe_rig, probe_rig_steps, run_steps
from .retarget import METHODS, RigTarget, character_deltas

__all__ = ["METHODS", "NonlinearResult", "PoseLibrary", "ProbeReport", "RigModel", "RigTarget", "character_deltas",
           "fit_model", "iterate_nonlinear", "probe_rig", "probe_rig_steps", "run_steps",
           "solve_nonlinear"]
