"""Type stubs of the native module `hybsim._hybsim` (PyO3). Use the
`hybsim` package's API (`hybsim.load`, `Model`, `Solution`); this module is
its engine room."""

from typing import Any, Dict, List, Optional, Tuple

SAMPLE_KINDS: List[str]

class ModelError(Exception):
    """A model that does not parse, check or compile; `str(err)` is the
    rendered file:line:col report."""

    diagnostics: List[Dict[str, Any]]

class SimulationError(Exception):
    """A run that failed at run time; `str(err)` names (t, j) and the model
    line."""

    diagnostics: List[Dict[str, Any]]
    partial: Any

class Model:
    """A compiled `.hyb` model."""

    @property
    def name(self) -> str: ...
    @property
    def file(self) -> str: ...
    @property
    def path(self) -> Optional[str]: ...
    @property
    def source(self) -> str: ...
    @property
    def overrides(self) -> List[Tuple[str, str]]: ...
    @property
    def state_names(self) -> List[str]: ...
    @property
    def output_names(self) -> List[str]: ...
    @property
    def rule_names(self) -> List[str]: ...
    @property
    def property_names(self) -> List[str]: ...
    @property
    def seed(self) -> int: ...
    @property
    def parameters(self) -> Dict[str, Any]: ...
    def run(self, seed: Optional[int] = None, sim: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
        """Simulates; returns the columns (`t`, `j`, `kind`, `x`, `jumps`, ...) and an OutputMap."""
    def design(self) -> Dict[str, Dict[str, Any]]:
        """Solves the design and check blocks."""
    def test(
        self,
        cases: int = 100,
        seed: Optional[int] = None,
        properties: Optional[List[str]] = None,
        max_shrink: int = 400,
    ) -> Dict[str, Any]:
        """Property test; returns the report as a dict."""

class OutputMap:
    """The outputs of the model a solution came from."""

    @property
    def names(self) -> List[str]: ...
    def __call__(self, t: Any, x: Any) -> Any:
        """Outputs at times t (n,) and states x (n, d): an (n, m) array."""

def compile(name: str, text: str, set: List[Tuple[str, str]], path: Optional[str] = None) -> Model:
    """Parses, checks and compiles `text`; raises ModelError."""

def parse_axis(text: str) -> Tuple[str, List[float]]:
    """``name=values`` as ``hybsim sweep --grid`` reads it; ValueError if malformed."""

def sweep(
    model: Model,
    grid: Optional[List[Tuple[str, List[float]]]] = None,
    runs: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
) -> Dict[str, Any]:
    """A sweep as ``hybsim sweep`` runs it: ``runs`` and ``points`` as dicts of columns, ``axes``, ``metrics``, ``seed``, ``runs_per_point``."""
