"""Sweeps and Monte Carlo from Python: :meth:`Model.sweep` runs a grid of
parameter values × seeded runs on all cores exactly as ``hybsim sweep`` does
(same seeds, same metrics, same tables) and returns the tables as columns."""

from __future__ import annotations

from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _hybsim

#: A grid: ``{"lambda": [0.5, 0.8], "g": "9:0.5:10"}`` (values, or a range
#: ``a:step:b`` / list as ``--grid`` writes it), the same as ``(name, values)``
#: pairs (``[("lambda", [0.5, 0.8])]``), or ``["lambda=0.5:0.1:0.9"]``.
Grid = Union[Mapping[str, Any], Sequence[Union[str, Tuple[str, Any]]]]


def _axis(name: Any, values: Any) -> Tuple[str, List[float]]:
    """One axis from its name and values (a list or array of numbers, a
    number, or a str as ``--grid`` writes the values)."""
    if isinstance(values, str):
        return _hybsim.parse_axis(f"{name}={values}")
    if values is None:
        raise TypeError(f"grid axis `{name}`: None is not a value")
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(
            f"grid axis `{name}`: a number, a sequence of numbers or a range "
            f"\"a:step:b\", not {type(values).__name__}"
        ) from e
    if arr.ndim > 1:
        # Flattened, a matrix would silently become its entries' grid.
        raise ValueError(
            f"grid axis `{name}`: the values of an axis are numbers, "
            f"got a {arr.ndim}-D array of shape {arr.shape}"
        )
    arr = arr.reshape(-1)
    if arr.size == 0:
        raise ValueError(f"grid axis `{name}` has no value")
    return (str(name), [float(v) for v in arr])


def _axes(grid: Grid) -> List[Tuple[str, List[float]]]:
    """``grid`` as ``(name, values)`` pairs, in order."""
    if isinstance(grid, str):
        grid = [grid]
    if isinstance(grid, Mapping):
        return [_axis(name, values) for name, values in grid.items()]
    if not isinstance(grid, (list, tuple)):
        raise TypeError(
            "grid= takes {name: values}, (name, values) pairs or \"name=a:step:b\" "
            f"strings, not {type(grid).__name__}"
        )
    axes = []
    for item in grid:
        if isinstance(item, str):
            axes.append(_hybsim.parse_axis(item))
        elif isinstance(item, (list, tuple)) and len(item) == 2 and isinstance(item[0], str):
            # `list(d.items())`: the pairs of a dict, in order.
            axes.append(_axis(*item))
        else:
            raise TypeError(
                f"grid axis {item!r}: a (name, values) pair or a \"name=a:step:b\" string"
            )
    return axes


class Table(Mapping[str, Any]):
    """A result table: named columns of equal length, in order. Numbers are
    numpy arrays (``uint64`` indices, counts and seeds; ``float64`` values,
    NaN where missing), text columns lists of str. ``len(table)`` is the
    number of rows; ``table["rate"]`` a column."""

    def __init__(self, columns: Dict[str, Any]):
        self._columns = columns

    def __getitem__(self, name: str) -> Any:
        try:
            return self._columns[name]
        except KeyError:
            known = ", ".join(self._columns)
            raise KeyError(f"no column `{name}` (columns: {known})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._columns)

    def __len__(self) -> int:
        first = next(iter(self._columns.values()), [])
        return len(first)

    @property
    def columns(self) -> List[str]:
        """The column names, in order."""
        return list(self._columns)

    def to_pandas(self):
        """The table as a pandas DataFrame (needs pandas)."""
        import pandas as pd

        return pd.DataFrame(self._columns)

    def to_polars(self):
        """The table as a polars DataFrame (needs polars)."""
        import polars as pl

        return pl.DataFrame(self._columns)

    def __repr__(self) -> str:
        return f"<hybsim.Table: {len(self)} rows × {len(self._columns)} columns>"


class Sweep:
    """The results of :meth:`Model.sweep`, as ``hybsim sweep`` writes them.

    ``runs``: one row per run (``point``, ``run``, ``seed``, the axes,
    ``status``, ``cause``, the metrics (NaN unless the run completed),
    ``message``, ``command``: the ``hybsim run`` line that replays it).
    ``points``: one row per grid point (``point``, the axes, ``runs``,
    ``completed``, then ``<metric>_mean``, ``_std``, ``_min``, ``_max``,
    ``_count`` over the completed runs). ``axes`` and ``metrics`` name
    them; ``seed`` is the base seed, ``runs_per_point`` the runs per point.
    """

    def __init__(self, data: Dict[str, Any]):
        self.runs = Table(data["runs"])
        self.points = Table(data["points"])
        self.axes: List[str] = list(data["axes"])
        self.metrics: List[str] = list(data["metrics"])
        self.seed: int = data["seed"]
        self.runs_per_point: int = data["runs_per_point"]

    @property
    def failed(self) -> List[int]:
        """The indices (into ``runs``) of the runs that did not complete."""
        return [i for i, s in enumerate(self.runs["status"]) if s != "completed"]

    def __repr__(self) -> str:
        return (
            f"<hybsim.Sweep: {len(self.points)} grid points × {self.runs_per_point} runs, "
            f"metrics {', '.join(self.metrics) or '(none)'}>"
        )


def check_count(name: str, value: Optional[int], minimum: int) -> None:
    """A count is None or an int of at least ``minimum`` that the engine's
    unsigned integers hold: anything else is refused here, named, rather
    than by the conversion (``OverflowError`` for -1, a vacuous pass for
    ``cases=0``)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"`{name}`: an int, got {type(value).__name__}")
    if not minimum <= int(value) < 2**63:
        raise ValueError(f"`{name}`: must be at least {minimum} (and below 2^63), got {int(value)}")


def check_seed(seed: Optional[int]) -> None:
    """A seed is None or an int in [0, 2^64): anything else is refused
    here, named, rather than by the conversion to the engine's u64."""
    if seed is None:
        return
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"`seed`: an int, got {type(seed).__name__}")
    if not 0 <= int(seed) < 2**64:
        raise ValueError(f"`seed`: must be from 0 to 2^64 - 1, got {int(seed)}")


def sweep_model(
    native: "_hybsim.Model",
    grid: Optional[Grid],
    runs: Optional[int],
    seed: Optional[int],
    threads: Optional[int],
) -> Sweep:
    """The body of :meth:`Model.sweep`."""
    check_seed(seed)
    check_count("runs", runs, 1)
    check_count("threads", threads, 1)
    axes = None if grid is None else _axes(grid)
    return Sweep(_hybsim.sweep(native, axes, runs, seed, threads))
