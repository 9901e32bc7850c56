"""hybsim from Python: simulate, design and property-test hybrid dynamical
systems written in the `.hyb` language, with results as numpy arrays.

>>> import hybsim
>>> ball = hybsim.load("models/bouncing_ball.hyb", set={"lambda": 0.7})
>>> sol = ball.run(T=3)
>>> sol.t, sol["h"], sol.jumps.t          # numpy arrays
>>> hybsim.plot.flows(sol)                 # HyEQ-style figure (matplotlib)

- :func:`load` / :class:`Model`: compile a model (errors: :class:`ModelError`
  with the rendered ``file:line:col`` report);
- :meth:`Model.run` -> :class:`Solution` (``t``, ``j``, ``x``, ``sol["h"]``,
  ``jumps``, ``termination``, ``restrict_t``/``restrict_j``/``interpolate``,
  ``to_pandas``/``to_polars``);
- :meth:`Model.design` -> the design blocks' results and reports;
- :meth:`Model.test` -> :class:`TestReport` with the shrunk counterexample;
- :meth:`Model.sweep` / :func:`sweep` -> :class:`Sweep` (tables ``runs``
  and ``points`` of a grid × Monte Carlo, as ``hybsim sweep``);
- :mod:`hybsim.plot` -> ``flows``, ``jumps``, ``hybrid``, ``phase``.
"""

from . import _hybsim
from .model import (
    Counterexample,
    Model,
    ModelError,
    SimulationError,
    TestReport,
    load,
    run,
    sweep,
)
from .solution import SAMPLE_KINDS, Jumps, Solution, Termination
from .sweep import Sweep, Table

__all__ = [
    "Counterexample",
    "Jumps",
    "Model",
    "ModelError",
    "SAMPLE_KINDS",
    "SimulationError",
    "Solution",
    "Sweep",
    "Table",
    "Termination",
    "TestReport",
    "load",
    "plot",
    "run",
    "sweep",
]

__version__ = "0.1.0"


def __getattr__(name):
    # `hybsim.plot` imports matplotlib only when first used.
    if name == "plot":
        import importlib

        return importlib.import_module(".plot", __name__)
    raise AttributeError(f"module 'hybsim' has no attribute '{name}'")
