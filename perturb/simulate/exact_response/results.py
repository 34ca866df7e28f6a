"""Result objects of the exact frequency response: ``SpecialPoint``,
``ContinuationPoint``, ``ContinuationBranch`` (with its polishing of an orbit at an exact
parameter value, ``polish_at``) and ``ExactBranches``.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.response import Branch, Response
from perturb.simulate.exact_response.base import NODE_GROWTH, SpecialKind
from perturb.simulate.exact_response.problem import nodes_needed
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
    multiple_shooting,
    periodic_orbit,
)


# =============================================================================================
# result objects
# =============================================================================================
@dataclass(frozen=True)
class SpecialPoint:
    """A bifurcation or grazing located between two consecutive points of a branch.

    Attributes
    ----------
    kind : str
        ``'fold'``, ``'branch_point'`` (a multiplier through +1 without a fold: symmetry-
        breaking pitchfork or transcritical point), ``'period_doubling'`` (through -1),
        ``'torus'`` (a complex pair through the unit circle) or ``'grazing'`` (the orbit
        becomes tangent to a breakpoint; the number of switches per period changes).
    index : int
        The point before it (it lies between ``points[index]`` and ``points[index + 1]``).
    parameter, amplitude : float
        Linear interpolation of the test function's zero.
    y0 : tuple of float
        Interpolated ``(x, v)`` at ``t0`` (the whole state for a system).
    """

    kind: SpecialKind
    index: int
    parameter: float
    amplitude: float
    y0: tuple[float, ...]

    def __repr__(self) -> str:
        return (
            f"SpecialPoint({self.kind} at p = {self.parameter:.6g}, amplitude "
            f"{self.amplitude:.6g}, after point {self.index})"
        )


@dataclass(frozen=True, eq=False)
class ContinuationPoint:
    """A converged periodic orbit on a branch.

    Attributes
    ----------
    parameter : float
    y0 : ndarray, shape (2,) or (n,)
        ``(x, v)`` at ``t0`` (read-only); a system's state ``(q, q', p)``.
    multipliers : ndarray of complex, shape (2,) or (n,)
        Floquet multipliers by decreasing modulus.
    max_multiplier : float
        Largest modulus (capped at ``1e300``).
    stable : bool
        ``max_multiplier < 1``.
    amplitude, first_harmonic_amplitude, mean : float
        ``max |x|`` over the orbit period, the amplitude of the component at the forcing
        frequency, and the mean of ``x`` (for a system: of its output ``c . y``).
    tangent : ndarray, shape (3,) or (n + 1,)
        Unit tangent in scaled ``(x0, v0, p)`` (``(y0, p)`` for a system; state over the
        orbit size, parameter over the window), oriented along the branch.
    switches : int
        Breakpoint crossings per orbit period (``-1`` for smooth flows, which do not count).
    source : str
        ``'closed form'`` (orbit inside one linear segment: exact formula), ``'shooting'``,
        ``'multiple shooting'`` or ``'mirror'`` (image of another branch's orbit under the
        symmetry of an odd system).
    signature : ndarray, shape (16m,) or (8mn,)
        ``(x, v)`` (every state) at ``t0 + kT/8``, ``k = 0 .. 8m-1``: with the amplitude,
        first harmonic and mean, what the proximity tests (joins, closed loops, duplicate
        seeds) compare.
    nodes : ndarray or None
        Multiple-shooting nodes ``(N, 2)`` (``(N, n)``) when ``N > 1``.
    coordinate_amplitudes, coordinate_means : ndarray or None
        Systems only (None for an oscillator): ``max_t |q_k(t)|`` and the mean of ``q_k`` for
        every coordinate ``q_k`` (second-order coordinates, then first-order states; the
        order of :attr:`ContinuationBranch.coordinates`).
    """

    parameter: float
    y0: np.ndarray
    multipliers: np.ndarray
    max_multiplier: float
    stable: bool
    amplitude: float
    first_harmonic_amplitude: float
    mean: float
    tangent: np.ndarray
    switches: int
    source: str
    signature: np.ndarray
    nodes: np.ndarray | None = None
    coordinate_amplitudes: np.ndarray | None = None
    coordinate_means: np.ndarray | None = None

    def __repr__(self) -> str:
        if self.y0.size != 2:
            ys = ", ".join(f"{v:.8g}" for v in self.y0)
            return (
                f"ContinuationPoint(p={self.parameter:.8g}, y0=({ys}), "
                f"amplitude={self.amplitude:.8g}, "
                f"{'stable' if self.stable else 'unstable'}, max|mu|={self.max_multiplier:.4g}, "
                f"{self.source})"
            )
        return (
            f"ContinuationPoint(p={self.parameter:.8g}, y0=({self.y0[0]:.8g}, {self.y0[1]:.8g}), "
            f"amplitude={self.amplitude:.8g}, {'stable' if self.stable else 'unstable'}, "
            f"max|mu|={self.max_multiplier:.4g}, {self.source})"
        )


@dataclass(frozen=True, eq=False)
class ContinuationBranch:
    """A traced branch of period-``m`` orbits, ordered along the curve.

    Attributes
    ----------
    parameter : str
        Name of the continuation parameter.
    m : int
        Forcing periods per orbit period.
    t0 : float
        Phase of the section where ``y0`` is taken.
    window : tuple of float
        Parameter range of the run.
    points : tuple of ContinuationPoint
    special_points : tuple of SpecialPoint
    closed : bool
        The branch is a closed loop (an isola if no other branch reaches it).
    stop_reason : str
        Why each end stopped (``'backward end / forward end'``).
    periods : float
        Work: propagated time in forcing periods (the exact propagator dominates the cost).
    family : FlowFamily
        The flows (not printed).
    ds_max : float
        Output spacing of the run.
    coordinates : tuple of str
        Systems: the names of the coordinates whose statistics every point carries
        (``coordinate_amplitudes``, ``coordinate_means``); empty for an oscillator.
    output : str
        Systems: what ``amplitude``, ``first_harmonic_amplitude`` and ``mean`` measure (a
        coordinate name or combination); empty for an oscillator (``x``).
    output_vector : ndarray or None
        Systems: the output as a combination of the states (``System.output``).
    """

    parameter: str
    m: int
    t0: float
    window: tuple[float, float]
    points: tuple[ContinuationPoint, ...]
    special_points: tuple[SpecialPoint, ...]
    closed: bool
    stop_reason: str
    periods: float
    family: FlowFamily = field(repr=False, compare=False)
    ds_max: float = 0.005
    coordinates: tuple[str, ...] = ()
    output: str = ""
    output_vector: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        if not self.points:
            return "ContinuationBranch(empty)"
        p, a = self.parameters, self.amplitudes
        shape = "closed loop" if self.closed else f"ends: {self.stop_reason}"
        kinds = ", ".join(
            f"{n} {k}{'s' if n > 1 else ''}"
            for k in ("fold", "branch_point", "period_doubling", "torus", "grazing")
            if (n := sum(s.kind == k for s in self.special_points))
        )
        return (
            f"ContinuationBranch(period {self.m}, {len(self)} points, {self.parameter} "
            f"{p.min():.4g}..{p.max():.4g}, amplitude {a.min():.4g}..{a.max():.4g}, "
            f"{int(sum(q.stable for q in self.points))} stable, {kinds or 'no special points'}, "
            f"{shape})"
        )

    # -- arrays --------------------------------------------------------------------------------
    @property
    def parameters(self) -> np.ndarray:
        return np.array([q.parameter for q in self.points])

    @property
    def amplitudes(self) -> np.ndarray:
        return np.array([q.amplitude for q in self.points])

    @property
    def states(self) -> np.ndarray:
        """``y0`` of every point, shape ``(points, 2)`` (``(points, n)`` for a system)."""
        width = self.points[0].y0.size if self.points else 2
        return np.array([q.y0 for q in self.points]).reshape(-1, width)

    @property
    def coordinate_amplitudes(self) -> np.ndarray:
        """Systems: ``max |q_k|`` of every point and coordinate, shape
        ``(points, len(coordinates))`` (``(points, 0)`` for an oscillator)."""
        k = len(self.coordinates)
        return np.array(
            [q.coordinate_amplitudes if k else () for q in self.points], dtype=float
        ).reshape(-1, k)

    @property
    def coordinate_means(self) -> np.ndarray:
        """Systems: the mean of ``q_k`` of every point and coordinate (as
        :attr:`coordinate_amplitudes`)."""
        k = len(self.coordinates)
        return np.array(
            [q.coordinate_means if k else () for q in self.points], dtype=float
        ).reshape(-1, k)

    def columns(self) -> dict[str, np.ndarray]:
        """Systems: the extra columns of every point, ``amplitude_<name>`` and
        ``mean_<name>`` per coordinate (in :attr:`coordinates` order, amplitudes first);
        empty for an oscillator."""
        amps, means = self.coordinate_amplitudes, self.coordinate_means
        out: dict[str, np.ndarray] = {}
        for k, name in enumerate(self.coordinates):
            out[f"amplitude_{name}"] = amps[:, k].copy()
        for k, name in enumerate(self.coordinates):
            out[f"mean_{name}"] = means[:, k].copy()
        return out

    def _kind(self, kind: str) -> tuple[SpecialPoint, ...]:
        return tuple(s for s in self.special_points if s.kind == kind)

    @property
    def folds(self) -> tuple[SpecialPoint, ...]:
        return self._kind("fold")

    @property
    def branch_points(self) -> tuple[SpecialPoint, ...]:
        return self._kind("branch_point")

    @property
    def period_doublings(self) -> tuple[SpecialPoint, ...]:
        return self._kind("period_doubling")

    @property
    def grazings(self) -> tuple[SpecialPoint, ...]:
        return self._kind("grazing")

    # -- conversions ---------------------------------------------------------------------------
    def to_branch(self) -> Branch:
        """The :class:`~perturb.response.Branch` with the standard columns."""
        pts = self.points
        return Branch(
            omega=[q.parameter for q in pts],
            amplitude=[q.amplitude for q in pts],
            first_harmonic_amplitude=[q.first_harmonic_amplitude for q in pts],
            mean=[q.mean for q in pts],
            stable=[q.stable for q in pts],
            max_multiplier=[q.max_multiplier for q in pts],
        )

    def orbit(self, index: int, *, tol: float = 1e-12) -> PeriodicOrbit:
        """The :class:`~perturb.simulate.orbits.shooting.PeriodicOrbit` at ``points[index]``,
        polished
        by shooting (multiple shooting on the stored nodes for strongly unstable orbits)."""
        q = self.points[index]
        flow = self.family.at(q.parameter)
        if q.nodes is not None:
            return multiple_shooting(flow, q.nodes, m=self.m, t0=self.t0, tol=tol)
        return periodic_orbit(flow, q.y0, m=self.m, t0=self.t0, tol=tol)

    def orbit_at(self, index: int, value: float) -> PeriodicOrbit | None:
        """The orbit at exactly the parameter ``value`` between ``points[index]`` and
        ``points[index + 1]``: their states interpolated linearly in the parameter, then
        shooting at ``value`` (multiple shooting when both carry nodes or the orbit is
        strongly unstable); None when shooting fails there."""
        if not 0 <= int(index) < len(self.points) - 1:
            raise ParameterError(f"index = {index!r}: expected 0 <= index < {len(self.points) - 1}")
        return polish_at(self, int(index), float(value))


@dataclass(frozen=True, eq=False)
class ExactBranches:
    """Every branch found by :func:`exact_branches`, with the work it took.

    Attributes
    ----------
    branches : tuple of ContinuationBranch
    mirror_of : tuple of (int or None)
        For each branch, the branch it is the symmetric image of (odd systems), else None.
    notes : tuple of str
        What was done and what was skipped (budget, failed seeds).
    periods : float
        Propagated time in forcing periods (continuation, seeds and sweeps).
    seconds : float
        Wall-clock time.
    model : str
    params : mapping
    method : str
        ``'exact'`` for the exact PWL propagator, ``'shooting'`` for the ODE flow.
    coordinates : tuple of str
        Systems: the coordinates whose statistics every point carries (see
        :meth:`columns`); empty for an oscillator.
    output : str
        Systems: what the ``amplitude`` column measures; empty for an oscillator.
    """

    branches: tuple[ContinuationBranch, ...]
    mirror_of: tuple[int | None, ...]
    notes: tuple[str, ...]
    periods: float
    seconds: float
    model: str
    params: Any
    method: str
    coordinates: tuple[str, ...] = ()
    output: str = ""

    def columns(self) -> tuple[dict[str, np.ndarray], ...]:
        """Systems: per branch (the order of :meth:`to_response`), the extra columns
        ``amplitude_<name>``, ``mean_<name>`` of every coordinate (:meth:`ContinuationBranch.
        columns`); empty dicts for an oscillator."""
        return tuple(b.columns() for b in self.branches)

    def __len__(self) -> int:
        return len(self.branches)

    def __repr__(self) -> str:
        lines = [
            f"ExactBranches({self.model}: {len(self.branches)} branches, "
            f"{sum(len(b) for b in self.branches)} points, {self.periods:.0f} periods "
            f"propagated, {self.seconds:.2f} s)"
        ]
        for i, (b, mo) in enumerate(zip(self.branches, self.mirror_of, strict=True)):
            lines.append(f"  {i}: {b!r}" + (f" [mirror of {mo}]" if mo is not None else ""))
        return "\n".join(lines)

    def to_response(self) -> Response:
        """The :class:`~perturb.response.Response` (CSV columns of the project)."""
        notes = []
        for i, (b, mo) in enumerate(zip(self.branches, self.mirror_of, strict=True)):
            what = "closed loop" if b.closed else b.stop_reason
            extra = f", mirror image of branch {mo}" if mo is not None else ""
            per = f", period {b.m}" if b.m != 1 else ""
            notes.append(f"branch {i}: {what}{extra}{per}")
        folds = tuple(
            (s.parameter, s.amplitude)
            for b in self.branches
            for s in b.special_points
            if s.kind == "fold"
        )
        return Response(
            tuple(b.to_branch() for b in self.branches),
            self.method,
            self.model,
            dict(self.params),
            folds=folds,
            notes=tuple(notes) + self.notes,
        )


def polish_at(branch: ContinuationBranch, j: int, w: float) -> PeriodicOrbit | None:
    """The orbit of ``branch`` at exactly ``Omega = w`` between points ``j`` and ``j + 1``:
    the stored states interpolated linearly in the parameter, then shooting at ``w`` (multiple
    shooting when both points carry nodes, as strongly unstable orbits need)."""
    a, b = branch.points[j], branch.points[j + 1]
    dp = b.parameter - a.parameter
    s = 0.5 if dp == 0.0 else min(1.0, max(0.0, (w - a.parameter) / dp))
    flow = branch.family.at(w)
    try:
        if a.nodes is not None and b.nodes is not None and a.nodes.shape == b.nodes.shape:
            nodes = (1.0 - s) * a.nodes + s * b.nodes
            return multiple_shooting(flow, nodes, m=branch.m, t0=branch.t0)
        y = (1.0 - s) * a.y0 + s * b.y0
        orbit = periodic_orbit(flow, y, m=branch.m, t0=branch.t0)
        if orbit.max_multiplier > NODE_GROWTH:
            # one period from y0 amplifies its rounding by the multiplier: the statistics of a
            # strongly unstable orbit come from nodes that each grow it by NODE_GROWTH at most
            n = nodes_needed(orbit.max_multiplier, branch.m)
            if y.size != 2:
                _, Y = orbit.sample_states(n)
                return multiple_shooting(flow, Y.T.copy(), m=branch.m, t0=branch.t0)
            _, x, v = orbit.sample(n)
            orbit = multiple_shooting(flow, np.column_stack([x, v]), m=branch.m, t0=branch.t0)
        return orbit
    except PerturbError:
        return None
