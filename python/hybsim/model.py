"""Loading `.hyb` models and their three verbs: :meth:`Model.run`,
:meth:`Model.design`, :meth:`Model.test`."""

from __future__ import annotations

import os
import shlex
from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _hybsim
from .solution import Solution
from .sweep import Grid, Sweep, check_count, check_seed, sweep_model

ModelError = _hybsim.ModelError
SimulationError = _hybsim.SimulationError

PathOrSource = Union[str, "os.PathLike[str]"]


def _overrides(set: Optional[Mapping[str, Any]]) -> List[Tuple[str, str]]:  # noqa: A002
    """``load(..., set=...)`` as ``(name, expression)`` pairs."""
    if set is None:
        return []
    if not isinstance(set, Mapping):
        raise TypeError(
            f"set= takes a dict of name: value, e.g. {{'lambda': 0.7}}, not {type(set).__name__}"
        )
    return [(str(k), _expression(str(k), v)) for k, v in set.items()]


def _expression(name: str, value: Any) -> str:
    """A Python value as a `.hyb` expression: numbers in their shortest
    round-trip form, 1-D sequences as column vectors ``[a; b]``, 2-D as
    matrices ``[a, b; c, d]``; a str is taken as written (any expression,
    e.g. ``"uniform(0, 2)"``). NaN has no `.hyb` spelling (``repr`` gives
    ``nan``, an unknown name): a ``ValueError`` naming ``name``."""
    if isinstance(value, str):
        return value
    if value is None:
        # numpy reads None as NaN: say what was passed, not "NaN".
        raise TypeError(
            f"set[{name!r}]: None is not a value; leave {name!r} out to keep the model's value"
        )
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(
            f"set[{name!r}]: a number, a nested sequence or array of numbers, or an "
            f"expression as str, not {type(value).__name__}"
        ) from e
    if np.isnan(arr).any():
        raise ValueError(f"set[{name!r}]: NaN is not a value of the model language")
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if arr.ndim == 0:
        return repr(float(arr))
    if arr.ndim == 1:
        return "[" + "; ".join(repr(float(v)) for v in arr) + "]"
    if arr.ndim == 2:
        return "[" + "; ".join(", ".join(repr(float(v)) for v in row) for row in arr) + "]"
    raise ValueError(f"a {arr.ndim}-D array is not a .hyb value (scalars, vectors, matrices)")


def _read_text(path: str, f: Any) -> str:
    """The text of the model file ``f`` as ``hybsim run`` reads it: at
    most ``MAX_SOURCE_BYTES`` (``/dev/zero`` was read until the memory ran
    out), UTF-8 with a bad byte placed at its line and column (it was
    UnicodeDecodeError's byte offset). ValueError otherwise."""
    limit = _hybsim.MAX_SOURCE_BYTES
    data = f.read(limit + 1)
    if len(data) > limit:
        raise ValueError(
            f"cannot read model file `{path}`: more than {limit >> 20} MiB, "
            "the limit for a model's text"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        prefix = data[: e.start].decode("utf-8")
        line = prefix.count("\n") + 1
        col = len(prefix.rsplit("\n", 1)[-1]) + 1
        raise ValueError(
            f"cannot read model file `{path}`: line {line}, column {col}: byte "
            f"0x{data[e.start]:02x} is not UTF-8 (save the file as UTF-8)"
        ) from None


def load(
    model: PathOrSource,
    set: Optional[Mapping[str, Any]] = None,  # noqa: A002 - mirrors `hybsim run --set`
    *,
    name: Optional[str] = None,
) -> "Model":
    """Parses, checks and compiles a `.hyb` model.

    Parameters
    ----------
    model
        A path (``str`` or ``os.PathLike``) to a `.hyb` file, or the model's
        source text (a ``str`` with a line break).
    set
        Overrides, as ``hybsim run --set``: ``{"lambda": 0.7, "K": [[1, 2]],
        "h": "uniform(0, 2)"}`` (numbers, nested sequences or numpy arrays,
        or expressions as str).
    name
        The file name diagnostics show for a model given as text (default
        ``"<string>"``).

    Raises
    ------
    ModelError
        If the model does not parse, check or compile: ``str(err)`` is the
        rendered ``file:line:col`` report, ``err.diagnostics`` a list of
        dicts (``code``, ``message``, ``file``, ``line``, ``col``, ...).
    FileNotFoundError
        If ``model`` names no file.
    ValueError
        If the file is not UTF-8 (the message gives the line and column of
        the first bad byte) or is larger than 16 MiB.
    """
    pairs = _overrides(set)
    if isinstance(model, os.PathLike) or (isinstance(model, str) and "\n" not in model):
        path = os.fspath(model)
        try:
            f = open(path, "rb")
        except FileNotFoundError as e:
            # A one-line model text is taken as a path: say so, not just "no such file".
            if isinstance(model, str) and model.lstrip().startswith("model "):
                raise FileNotFoundError(
                    e.errno,
                    f"{e.strerror}; a str without a line break is a path: "
                    "give the model text with its line breaks (or end it with one)",
                    path,
                ) from None
            raise
        with f:
            text = _read_text(path, f)
        native = _hybsim.compile(path, text, pairs, path)
    elif isinstance(model, str):
        native = _hybsim.compile(name or "<string>", model, pairs, None)
    else:
        raise TypeError(f"load() needs a path or the model text, not {type(model).__name__}")
    return Model(native)


def run(
    model: PathOrSource,
    set: Optional[Mapping[str, Any]] = None,  # noqa: A002
    **kwargs: Any,
) -> Solution:
    """``load(model, set).run(**kwargs)``: one call from a file to arrays."""
    return load(model, set).run(**kwargs)


def sweep(
    model: PathOrSource,
    set: Optional[Mapping[str, Any]] = None,  # noqa: A002
    **kwargs: Any,
) -> Sweep:
    """``load(model, set).sweep(**kwargs)``: a sweep from a file in one call."""
    return load(model, set).sweep(**kwargs)


@dataclass(frozen=True)
class Counterexample:
    """A failing case of a property test, shrunk.

    ``property`` failed at hybrid time ``(t, j)`` with state ``state``
    (for jumps: the pre-jump point); ``inputs`` are the shrunk sampled
    values (``sampled`` as first drawn), ``seed`` the case's seed, and
    ``replay`` the ``hybsim run`` command that reproduces it bit for bit
    (of a model given as text, with ``-`` as the model: pipe
    ``model.source`` into it).
    """

    property: str
    statement: str
    t: float
    j: int
    state: np.ndarray
    state_names: List[str]
    message: str
    case: int
    seed: int
    inputs: Dict[str, float]
    sampled: Dict[str, float]
    horizon_T: Optional[float]
    horizon_J: Optional[int]
    shrink_runs: int
    description: str
    replay_args: List[str]

    @property
    def replay(self) -> str:
        """The replay command as one shell line."""
        return shlex.join(self.replay_args)

    @property
    def set(self) -> Dict[str, float]:
        """The inputs as ``load(..., set=...)`` overrides."""
        return dict(self.inputs)

    def run_kwargs(self) -> Dict[str, Any]:
        """Keywords for :meth:`Model.run` that replay the case on a model
        loaded with ``set=cx.set``: ``seed`` and any shrunk horizon."""
        kw: Dict[str, Any] = {"seed": self.seed}
        if self.horizon_T is not None:
            kw["T"] = self.horizon_T
        if self.horizon_J is not None:
            kw["J"] = self.horizon_J
        return kw


@dataclass(frozen=True)
class TestReport:
    """The result of :meth:`Model.test`.

    ``outcome`` is ``"passed"``, ``"failed"`` (``counterexamples`` holds one
    shrunk counterexample per failing property, as ``hybsim test`` reports
    them; ``counterexample`` is the first) or
    ``"error"`` (a case could not run; ``error`` holds its message and
    replay command). ``bool(report)`` is True iff every case passed;
    ``str(report)`` is the text ``hybsim test`` prints.
    """

    __test__ = False  # not a pytest test class

    model: str
    outcome: str
    passed: bool
    cases: int
    cases_run: int
    inconclusive: int
    seed: int
    properties: List[str]
    inputs: List[tuple]
    counterexample: Optional[Counterexample]
    counterexamples: List[Counterexample]
    error: Optional[Dict[str, Any]]

    def __bool__(self) -> bool:
        return self.passed

    def __str__(self) -> str:
        sampled = ", ".join(f"{n} ~ {d}" for n, d in self.inputs) or "no named input"
        lines = [
            f"testing {len(self.properties)} propert{'y' if len(self.properties) == 1 else 'ies'} "
            f"of {self.model} on {self.cases} case{'' if self.cases == 1 else 's'} "
            f"(master seed {self.seed}); sampled: {sampled}"
        ]
        if self.outcome == "passed":
            lines += [f"  ok  {p}" for p in self.properties]
        for cx in self.counterexamples:
            lines.append(f"FAILED  {cx.statement}")
            lines.append(cx.description.rstrip("\n"))
            lines.append(f"replay: {cx.replay}")
        if self.outcome == "error" and self.error is not None:
            lines.append(self.error["message"].rstrip("\n"))
            lines.append(f"replay: {shlex.join(self.error['replay'])}")
        lines.append(
            f"{self._verdict()}: "
            f"{self.cases_run} case{'' if self.cases_run == 1 else 's'}, "
            f"{self.inconclusive} inconclusive"
        )
        return "\n".join(lines)

    def _verdict(self) -> str:
        if self.outcome != "failed":
            return self.outcome
        n = len(self.counterexamples)
        return "counterexample" if n == 1 else f"{n} counterexamples"


def _counterexample(cx: Dict[str, Any]) -> Counterexample:
    """A counterexample of the native report."""
    return Counterexample(
        property=cx["property"],
        statement=cx.get("statement", cx["property"]),
        t=cx["t"],
        j=cx["j"],
        state=cx["state"],
        state_names=list(cx["state_names"]),
        message=cx["message"],
        case=cx["case"],
        seed=cx["seed"],
        inputs=dict(cx["inputs"]),
        sampled=dict(cx["sampled"]),
        horizon_T=cx["horizon_T"],
        horizon_J=cx["horizon_J"],
        shrink_runs=cx["shrink_runs"],
        description=cx["description"],
        replay_args=list(cx["replay"]),
    )


class Model:
    """A compiled `.hyb` model (from :func:`load`).

    Attributes: ``name``, ``file``, ``path``, ``source``, ``overrides``,
    ``state_names``, ``output_names``, ``rule_names``, ``property_names``,
    ``seed``, ``parameters`` (resolved, design results included).
    """

    def __init__(self, native: "_hybsim.Model"):
        # `Model("ball.hyb")` is a natural first guess: say what to call.
        if not isinstance(native, _hybsim.Model):
            raise TypeError(
                "hybsim.Model is made by hybsim.load(path_or_source, set=...), "
                f"not from a {type(native).__name__}: write hybsim.load({native!r})"
            )
        self._native = native

    @property
    def name(self) -> str:
        """The model's name (``model NAME``)."""
        return self._native.name

    @property
    def file(self) -> str:
        """The file name (or label) diagnostics show."""
        return self._native.file

    @property
    def path(self) -> Optional[str]:
        """The path the model was read from, or None for source text."""
        return self._native.path

    @property
    def source(self) -> str:
        """The model's source text."""
        return self._native.source

    @property
    def overrides(self) -> List[Tuple[str, str]]:
        """The overrides applied, as ``(name, expression)`` pairs."""
        return self._native.overrides

    @property
    def state_names(self) -> List[str]:
        """One name per scalar state component (``h``, ``x[2]``, ``P[1,2]``)
        the model declares, as ``Solution.names``: not the timers the language
        adds for ``every`` and held ``noise``."""
        return self._native.state_names

    @property
    def output_names(self) -> List[str]:
        """One name per scalar output component."""
        return self._native.output_names

    @property
    def rule_names(self) -> List[str]:
        """The jump rules' names, in declaration order."""
        return self._native.rule_names

    @property
    def property_names(self) -> List[str]:
        """The declared properties' names, in order."""
        return self._native.property_names

    @property
    def seed(self) -> int:
        """The seed of ``sim { seed }`` (default 0)."""
        return self._native.seed

    @property
    def parameters(self) -> Dict[str, Any]:
        """Resolved parameters (overrides and design results applied): a float, a 1-D array (vectors) or a 2-D array (matrices) each; random parameters hold their distribution's centre (a run draws them from its seed)."""
        return self._native.parameters

    def __repr__(self) -> str:
        return repr(self._native)

    def run(
        self,
        T: Optional[float] = None,
        J: Optional[int] = None,
        seed: Optional[int] = None,
        **sim: Any,
    ) -> Solution:
        """Simulates the model and returns the solution as numpy arrays.

        ``T``, ``J``: horizons (default: the model's ``sim`` block);
        ``seed``: the run's seed (default: the model's; random parameters
        and initial values are drawn from it exactly as ``hybsim run --seed``
        does). Further keywords override the ``sim`` block as ``hybsim run``'s
        flags do: ``dt_out``, ``solver`` (``"dopri5"``, ``"dop853"``,
        ``"radau5"``, ``"bdf"``, ``"auto"``, ``"rk4"``, ``"euler_maruyama"``),
        ``rtol``, ``atol``, ``step``,
        ``max_step``, ``priority`` (``"jumps"``, ``"flows"``, ``"random"``),
        ``jump_choice`` (``"first"``, ``"random"``: which of several enabled
        rules fires), ``event_tol``, ``guard_checks``, ``zeno_max_rate``, ``zeno_window``,
        ``max_total_jumps``, ``exact_affine`` (``"auto"``, ``"on"``,
        ``"off"``, or a bool), ``linear_solver`` (``"auto"``,
        ``"dense"``, ``"sparse"``: the implicit solvers' LU).

        The run releases the GIL; Ctrl-C stops it with KeyboardInterrupt.

        Raises
        ------
        SimulationError
            If the run fails (non-finite state, integrator failure): the
            message points at (t, j) and the model line; ``err.partial`` is
            the solution up to there.
        ValueError, TypeError
            For invalid or unknown settings.
        """
        if T is not None:
            sim["T"] = T
        if J is not None:
            sim["J"] = J
        check_seed(seed)
        try:
            data = self._native.run(seed, sim)
        except SimulationError as e:
            partial = getattr(e, "partial", None)
            if isinstance(partial, dict):
                e.partial = Solution(partial)
            raise
        return Solution(data)

    def sweep(
        self,
        grid: Optional[Grid] = None,
        runs: Optional[int] = None,
        seed: Optional[int] = None,
        threads: Optional[int] = None,
    ) -> Sweep:
        """Runs a sweep and Monte Carlo of the model, as ``hybsim sweep``
        does: every grid point × ``runs`` seeded runs, each reduced to the
        model's ``metric`` values while it streams, on ``threads`` threads
        (default: all cores) with the GIL released.

        ``grid``: ``{"lambda": [0.5, 0.8], "g": "9:0.5:10"}`` (values, or a
        range ``a:step:b`` or list as ``--grid`` writes it), the same as
        ``(name, values)`` pairs, or ``["lambda=0.5:0.1:0.9"]``; the first
        axis varies slowest. Any of
        ``grid``, ``runs``, ``seed`` left out comes from the model's
        ``sweep { }`` block, else no axis, one run and the model's seed. Run
        ``r`` of a point has the same seed as in ``hybsim sweep``, so a row's
        ``command`` replays it (``-`` for a model given as text: its
        ``source`` on standard input).

        Returns a :class:`Sweep` with the tables ``runs`` and ``points``
        (``to_pandas()``/``to_polars()``). A run that fails is a row
        (``status``, ``cause``, ``message``), not an exception; Ctrl-C stops
        the sweep with KeyboardInterrupt.

        Raises
        ------
        ModelError
            If the model does not compile as loaded, or an axis names
            nothing the model can be set by.
        ValueError
            For an axis set twice (or also in ``set``), a malformed axis, or
            more runs than a sweep allows.
        """
        return sweep_model(self._native, grid, runs, seed, threads)

    def design(self) -> Dict[str, Dict[str, Any]]:
        """Solves the model's ``design`` and ``check`` blocks (as ``hybsim
        design``; the GIL is released).

        Returns ``{block: report}``; each report has the fields of ``hybsim
        design --json`` (``name``, ``status``, ``objective``, solver figures,
        ...) with ``results`` as numpy values (a float for scalars, 1-D arrays
        for vectors, 2-D for matrices), plus ``summary`` (the one-line
        report), ``check`` and ``check_failed`` (a ``check`` block without
        solution).
        """
        return self._native.design()

    def test(
        self,
        cases: Optional[int] = None,
        seed: Optional[int] = None,
        properties: Optional[Sequence[str]] = None,
        max_shrink: int = 400,
    ) -> TestReport:
        """Property test (as ``hybsim test``): samples ``cases`` cases of the
        model's random inputs (default: 100, or 1 for a model without any
        random draw, whose cases would all be the same run) from master seed
        ``seed`` (default: the model's), checks the ``property`` declarations named in
        ``properties`` (default: all) on each, in parallel with the GIL
        released, and shrinks the first failure (at most ``max_shrink``
        runs).

        Returns a :class:`TestReport`; ``report.counterexamples`` has, for
        each failing property (as ``hybsim test`` reports them), the failing
        time, state, shrunk inputs and the replay command
        (``report.counterexample``: the first).
        Raises ValueError if the model declares no property or a name is
        unknown, if ``cases`` < 1 (as ``--cases 0``, it would pass
        vacuously), ``max_shrink`` < 0 or ``seed`` is outside [0, 2^64).
        """
        check_count("cases", cases, 1)
        check_count("max_shrink", max_shrink, 0)
        check_seed(seed)
        if isinstance(properties, str):
            properties = [properties]
        if properties is not None and len(properties) == 0:
            # An empty selection tested every property, as None does.
            raise ValueError("properties=[] selects no property; leave it out (None) to test all")
        d = self._native.test(
            cases, seed, list(properties) if properties is not None else None, max_shrink
        )
        counterexamples = [_counterexample(cx) for cx in d["counterexamples"]]
        return TestReport(
            model=d["model"],
            outcome=d["outcome"],
            passed=d["passed"],
            cases=d["cases"],
            cases_run=d["cases_run"],
            inconclusive=d["inconclusive"],
            seed=d["seed"],
            properties=list(d["properties"]),
            inputs=[tuple(i) for i in d["inputs"]],
            counterexample=counterexamples[0] if counterexamples else None,
            counterexamples=counterexamples,
            error=d["error"],
        )

