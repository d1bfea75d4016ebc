"""The description of a compartment network: compartments, connections, feed and outflow.

Plain Python and NumPy, immutable and hashable (it can be a static argument of a jitted
function). The JAX models in :mod:`axialmix.network` read the structure from it and take
the rates either from it or as separate arrays to differentiate.

Conventions (MODELS.md §3):

* ``k_ij`` (``Connection(source=i, target=j, rate=k_ij)``) is the fraction of the content
  of compartment i that moves to j per unit time (continuous time), or per step of length
  ``time_step`` (discrete time, the source's "flux" ``lambda_ij / N_i``).
* Matrices indexed by compartments pair (source, target) as (row, column):
  ``connection_matrix()[i, j] = k_ij`` and ``particle_moves()[i, j] = lambda_ij``. The
  generator of the JAX models is the transpose arrangement, ``dm/dt = K m`` with
  ``K[j, i] = k_ij`` (see :func:`axialmix.network.generator_matrix`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ["CompartmentNetwork", "Connection", "Inlet", "Outlet"]

_FORMAT_VERSION = 1


def _finite_number(value: object, what: str) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}.") from None
    if not math.isfinite(number):
        raise ValueError(f"{what} must be finite, got {number}.")
    return number


@dataclass(frozen=True)
class Connection:
    """A directed connection: a fraction ``rate`` of the content of ``source`` moves to ``target``.

    **Arguments:**

    - `source`: name of the compartment material leaves.
    - `target`: name of the compartment material enters.
    - `rate`: ``k_ij``, fraction of the content of `source` moved per unit time
      (continuous networks, 1/time) or per step (discrete networks, dimensionless).
    """

    source: str
    target: str
    rate: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "target", str(self.target))
        where = f"connection {self.source} -> {self.target}"
        rate = _finite_number(self.rate, f"rate of {where}")
        if rate < 0:
            raise ValueError(f"Negative rate {rate} for {where}.")
        object.__setattr__(self, "rate", rate)


@dataclass(frozen=True)
class Inlet:
    """A compartment that receives a share ``fraction`` of the feed.

    **Arguments:**

    - `compartment`: name of the receiving compartment.
    - `fraction`: share of the feed (the feed shares of a network sum to 1).
    """

    compartment: str
    fraction: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "compartment", str(self.compartment))
        fraction = _finite_number(self.fraction, f"feed fraction of inlet {self.compartment}")
        if fraction < 0:
            raise ValueError(f"Negative feed fraction {fraction} for inlet {self.compartment}.")
        object.__setattr__(self, "fraction", fraction)


@dataclass(frozen=True)
class Outlet:
    """A compartment that loses a fraction ``rate`` of its content out of the network.

    **Arguments:**

    - `compartment`: name of the compartment discharging over the weir.
    - `rate`: ``k_out``, fraction of its content leaving per unit time (continuous) or
      per step (discrete); 0 makes the outlet inactive.
    """

    compartment: str
    rate: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "compartment", str(self.compartment))
        rate = _finite_number(self.rate, f"outflow rate of outlet {self.compartment}")
        if rate < 0:
            raise ValueError(f"Negative outflow rate {rate} for outlet {self.compartment}.")
        object.__setattr__(self, "rate", rate)


def _as_connection(item: object) -> Connection:
    if isinstance(item, Connection):
        return item
    if isinstance(item, Mapping):
        return Connection(item["source"], item["target"], item["rate"])
    source, target, rate = item  # type: ignore[misc]
    return Connection(source, target, rate)


def _as_inlet(item: object) -> Inlet:
    if isinstance(item, Inlet):
        return item
    if isinstance(item, str):
        return Inlet(item, 1.0)
    if isinstance(item, Mapping):
        return Inlet(item["compartment"], item.get("fraction", 1.0))
    compartment, fraction = item  # type: ignore[misc]
    return Inlet(compartment, fraction)


def _as_outlet(item: object) -> Outlet:
    if isinstance(item, Outlet):
        return item
    if isinstance(item, Mapping):
        return Outlet(item["compartment"], item["rate"])
    compartment, rate = item  # type: ignore[misc]
    return Outlet(compartment, rate)


@dataclass(frozen=True)
class CompartmentNetwork:
    """An immutable, validated network of well-mixed compartments (MODELS.md §3).

    Construct it with keyword arguments; lists are accepted and stored as tuples.

    **Arguments:**

    - `compartments`: compartment names, unique, in the order used by every array.
    - `connections`: :class:`Connection` objects or ``(source, target, rate)`` triples.
    - `inlets`: :class:`Inlet` objects, ``(name, feed_fraction)`` pairs or bare names
      (fraction 1); the fractions must sum to 1. Empty for a closed (batch) network.
    - `outlets`: :class:`Outlet` objects or ``(name, k_out)`` pairs. Empty, or all
      rates 0, for a closed network.
    - `holdups`: amount held in each compartment (particles, kg, ...), or ``None`` when only
      the tracer dynamics matter. Needed for particle moves and throughput.
    - `time_step`: ``None`` for continuous time (rates per unit time); a positive step length
      for the source's discrete steps (rates are fractions moved per step).
    - `description`: free text kept in the JSON file.

    Invalid input raises ``ValueError`` with a one-line message naming the problem.
    """

    compartments: tuple[str, ...]
    connections: tuple[Connection, ...] = ()
    inlets: tuple[Inlet, ...] = ()
    outlets: tuple[Outlet, ...] = ()
    holdups: tuple[float, ...] | None = None
    time_step: float | None = None
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if isinstance(self.compartments, str):
            raise ValueError("compartments must be a sequence of names, not a single string.")
        names = tuple(str(name) for name in self.compartments)
        object.__setattr__(self, "compartments", names)
        object.__setattr__(self, "connections", tuple(map(_as_connection, self.connections)))
        object.__setattr__(self, "inlets", tuple(map(_as_inlet, self.inlets)))
        object.__setattr__(self, "outlets", tuple(map(_as_outlet, self.outlets)))
        if self.holdups is not None:
            holdups = tuple(
                _finite_number(h, f"holdup {k} of the network") for k, h in enumerate(self.holdups)
            )
            object.__setattr__(self, "holdups", holdups)
        if self.time_step is not None:
            object.__setattr__(self, "time_step", _finite_number(self.time_step, "time_step"))
        object.__setattr__(self, "description", str(self.description))
        self._validate()

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        names = self.compartments
        if not names:
            raise ValueError("A network needs at least one compartment.")
        seen: set[str] = set()
        for name in names:
            if not name:
                raise ValueError("Compartment names must be non-empty.")
            if name in seen:
                raise ValueError(f"Duplicate compartment name {name!r}.")
            seen.add(name)
        if self.holdups is not None:
            if len(self.holdups) != len(names):
                raise ValueError(
                    f"holdups has {len(self.holdups)} entries for {len(names)} compartments."
                )
            for name, h in zip(names, self.holdups, strict=True):
                if h <= 0:
                    raise ValueError(f"Holdup of compartment {name!r} must be positive, got {h}.")
        if self.time_step is not None and self.time_step <= 0:
            raise ValueError(f"time_step must be positive (or None), got {self.time_step}.")

        pairs: set[tuple[str, str]] = set()
        for c in self.connections:
            for end in (c.source, c.target):
                if end not in seen:
                    raise ValueError(
                        f"Connection {c.source} -> {c.target} refers to missing compartment "
                        f"{end!r}."
                    )
            if c.source == c.target:
                raise ValueError(f"Connection {c.source} -> {c.target} connects a compartment "
                                 "to itself.")
            if (c.source, c.target) in pairs:
                raise ValueError(f"Duplicate connection {c.source} -> {c.target}.")
            pairs.add((c.source, c.target))

        inlet_names = [i.compartment for i in self.inlets]
        for name in inlet_names:
            if name not in seen:
                raise ValueError(f"Inlet refers to missing compartment {name!r}.")
        if len(set(inlet_names)) != len(inlet_names):
            raise ValueError("An inlet compartment is listed twice.")
        if self.inlets:
            total = sum(i.fraction for i in self.inlets)
            if abs(total - 1.0) > 1e-9:
                raise ValueError(f"Inlet feed fractions must sum to 1, got {total:.12g}.")
        outlet_names = [o.compartment for o in self.outlets]
        for name in outlet_names:
            if name not in seen:
                raise ValueError(f"Outlet refers to missing compartment {name!r}.")
        if len(set(outlet_names)) != len(outlet_names):
            raise ValueError("An outlet compartment is listed twice.")

        if self.time_step is not None:
            leaving = dict.fromkeys(names, 0.0)
            for c in self.connections:
                if c.rate > 1:
                    raise ValueError(
                        f"Per-step fraction {c.rate} of connection {c.source} -> {c.target} "
                        "is above 1."
                    )
                leaving[c.source] += c.rate
            for o in self.outlets:
                if o.rate > 1:
                    raise ValueError(
                        f"Per-step outflow fraction {o.rate} of outlet {o.compartment} is above 1."
                    )
                leaving[o.compartment] += o.rate
            for name, total in leaving.items():
                if total > 1 + 1e-12:
                    raise ValueError(
                        f"Total fraction {total:.6g} leaving compartment {name!r} in one step "
                        "is above 1."
                    )

        active_outlets = [o.compartment for o in self.outlets if o.rate > 0]
        if active_outlets and self.inlets:
            reachable = self._reachable_from([i.compartment for i in self.inlets if i.fraction > 0])
            for name in active_outlets:
                if name not in reachable:
                    raise ValueError(f"Outlet {name!r} cannot be reached from the inlet.")

    def _reachable_from(self, starts: Iterable[str]) -> set[str]:
        neighbours: dict[str, list[str]] = {name: [] for name in self.compartments}
        for c in self.connections:
            if c.rate > 0:
                neighbours[c.source].append(c.target)
        reached = set(starts)
        frontier = list(reached)
        while frontier:
            node = frontier.pop()
            for nxt in neighbours[node]:
                if nxt not in reached:
                    reached.add(nxt)
                    frontier.append(nxt)
        return reached

    # ------------------------------------------------------------------ basic properties
    @property
    def n_compartments(self) -> int:
        """Number of compartments."""
        return len(self.compartments)

    @property
    def is_discrete(self) -> bool:
        """Whether rates are fractions per step of length ``time_step``."""
        return self.time_step is not None

    @property
    def is_closed(self) -> bool:
        """Whether nothing enters or leaves (a batch network): no inlet, no active outlet."""
        return not self.inlets and all(o.rate == 0 for o in self.outlets)

    def index(self, name: str) -> int:
        """Position of compartment `name` in every per-compartment array."""
        try:
            return self.compartments.index(name)
        except ValueError:
            raise ValueError(f"No compartment named {name!r}.") from None

    @property
    def rates(self) -> np.ndarray:
        """Connection rates in the order of ``connections`` (1/time or per step)."""
        return np.array([c.rate for c in self.connections], dtype=float)

    @property
    def outflow_rates(self) -> np.ndarray:
        """Outflow rates ``k_out`` in the order of ``outlets`` (1/time or per step)."""
        return np.array([o.rate for o in self.outlets], dtype=float)

    @property
    def sources(self) -> np.ndarray:
        """Source compartment index of each connection."""
        return np.array([self.index(c.source) for c in self.connections], dtype=int)

    @property
    def targets(self) -> np.ndarray:
        """Target compartment index of each connection."""
        return np.array([self.index(c.target) for c in self.connections], dtype=int)

    @property
    def outlet_indices(self) -> np.ndarray:
        """Compartment index of each outlet."""
        return np.array([self.index(o.compartment) for o in self.outlets], dtype=int)

    @property
    def feed_split(self) -> np.ndarray:
        """Share of the feed entering each compartment (zeros for a closed network)."""
        split = np.zeros(self.n_compartments)
        for inlet in self.inlets:
            split[self.index(inlet.compartment)] = inlet.fraction
        return split

    def connection_matrix(self) -> np.ndarray:
        """Rates as a matrix with ``[i, j] = k_ij`` (row: source, column: target)."""
        matrix = np.zeros((self.n_compartments, self.n_compartments))
        matrix[self.sources, self.targets] = self.rates
        return matrix

    def outflow_vector(self) -> np.ndarray:
        """Outflow rate ``k_out`` of each compartment (zero where there is no outlet)."""
        vector = np.zeros(self.n_compartments)
        np.add.at(vector, self.outlet_indices, self.outflow_rates)
        return vector

    # ------------------------------------------------------------------ particle moves
    def step_fractions(self, time_step: float | None = None) -> np.ndarray:
        """Fraction of each compartment moved along each connection in one step.

        **Arguments:**

        - `time_step`: step length for a continuous network (fractions ``k_ij * dt``);
          must be omitted or equal ``self.time_step`` for a discrete network.

        **Returns:**

        Array ``[i, j]`` = fraction of compartment i moved to j per step.
        """
        return self.connection_matrix() * self._step_scale(time_step)

    def outflow_fractions(self, time_step: float | None = None) -> np.ndarray:
        """Fraction of each compartment leaving the network per step (see `step_fractions`)."""
        return self.outflow_vector() * self._step_scale(time_step)

    def _step_scale(self, time_step: float | None) -> float:
        if self.time_step is not None:
            if time_step is not None and not math.isclose(time_step, self.time_step):
                raise ValueError(
                    f"time_step {time_step} differs from the network's step {self.time_step}."
                )
            return 1.0
        if time_step is None:
            raise ValueError("A continuous network needs a time_step to give per-step moves.")
        dt = _finite_number(time_step, "time_step")
        if dt <= 0:
            raise ValueError(f"time_step must be positive, got {dt}.")
        return dt

    def _holdup_array(self, holdups: Sequence[float] | np.ndarray | None) -> np.ndarray:
        if holdups is None:
            if self.holdups is None:
                raise ValueError("The network has no holdups; pass holdups explicitly.")
            return np.asarray(self.holdups, dtype=float)
        array = np.asarray(holdups, dtype=float)
        if array.shape != (self.n_compartments,):
            raise ValueError(
                f"holdups must have shape ({self.n_compartments},), got {array.shape}."
            )
        if not np.all(np.isfinite(array)) or np.any(array < 0):
            raise ValueError("holdups must be finite and non-negative.")
        return array

    def particle_moves(
        self,
        holdups: Sequence[float] | np.ndarray | None = None,
        time_step: float | None = None,
    ) -> np.ndarray:
        """Amount moved along each connection per step, ``lambda_ij = fraction_ij * N_i``.

        **Arguments:**

        - `holdups`: amount ``N_i`` in each compartment (default: the network's holdups).
        - `time_step`: step length, for a continuous network only (see `step_fractions`).

        **Returns:**

        Array ``[i, j]`` = ``lambda_ij``, amount (particles, kg) moved from i to j per step;
        not rounded, so a particle simulation decides how to make it an integer.
        """
        return self.step_fractions(time_step) * self._holdup_array(holdups)[:, None]

    def outflow_per_step(
        self,
        holdups: Sequence[float] | np.ndarray | None = None,
        time_step: float | None = None,
    ) -> np.ndarray:
        """Amount leaving each compartment over the weir per step, ``k_out * dt * N_i``."""
        return self.outflow_fractions(time_step) * self._holdup_array(holdups)

    def feed_per_step(
        self,
        holdups: Sequence[float] | np.ndarray | None = None,
        time_step: float | None = None,
    ) -> np.ndarray:
        """Feed into each compartment per step that replaces the outflow (steady throughput).

        **Returns:**

        Array: the total outflow per step shared among the inlets by their feed fractions.
        """
        return self.feed_split * self.outflow_per_step(holdups, time_step).sum()

    def holdup_balance(
        self,
        holdups: Sequence[float] | np.ndarray | None = None,
        time_step: float | None = None,
    ) -> np.ndarray:
        """Net change of each compartment's content per step with steady feed (0 = constant).

        **Returns:**

        Array: inflow (connections and feed) minus outflow (connections and weir) per step.
        Zero in every compartment means the particle simulation keeps compartment sizes fixed.
        """
        dt = 1.0 if self.time_step is not None else time_step
        moves = self.particle_moves(holdups, dt)
        return (
            moves.sum(axis=0)
            - moves.sum(axis=1)
            + self.feed_per_step(holdups, dt)
            - self.outflow_per_step(holdups, dt)
        )

    @property
    def throughput(self) -> float:
        """Steady outflow ``sum k_out N_out`` (amount per unit time; needs holdups)."""
        per = self.outflow_vector() @ self._holdup_array(None)
        return float(per / self.time_step) if self.time_step is not None else float(per)

    # ------------------------------------------------------------------ derived networks
    def with_holdups(self, holdups: Sequence[float] | np.ndarray | None) -> CompartmentNetwork:
        """The same network with other holdups."""
        return replace(self, holdups=None if holdups is None else tuple(map(float, holdups)))

    def with_rates(
        self,
        rates: Sequence[float] | np.ndarray | None = None,
        outflow_rates: Sequence[float] | np.ndarray | None = None,
    ) -> CompartmentNetwork:
        """The same structure with new connection rates and/or outflow rates (same order)."""
        connections = self.connections
        if rates is not None:
            rates = np.asarray(rates, dtype=float).reshape(-1)
            if rates.shape != (len(connections),):
                raise ValueError(f"rates must have {len(connections)} entries, got {rates.size}.")
            connections = tuple(
                Connection(c.source, c.target, float(r))
                for c, r in zip(connections, rates, strict=True)
            )
        outlets = self.outlets
        if outflow_rates is not None:
            outflow_rates = np.asarray(outflow_rates, dtype=float).reshape(-1)
            if outflow_rates.shape != (len(outlets),):
                raise ValueError(
                    f"outflow_rates must have {len(outlets)} entries, got {outflow_rates.size}."
                )
            outlets = tuple(
                Outlet(o.compartment, float(r)) for o, r in zip(outlets, outflow_rates, strict=True)
            )
        return replace(self, connections=connections, outlets=outlets)

    def discretised(self, time_step: float) -> CompartmentNetwork:
        """The discrete-step network with fractions ``k * time_step`` per step.

        Its expectation ``m_{k+1} = (I + K dt) m_k`` is the explicit Euler scheme of the
        continuous network; it converges to it as ``time_step -> 0``.
        """
        if self.time_step is not None:
            raise ValueError("The network is already discrete.")
        dt = _finite_number(time_step, "time_step")
        if dt <= 0:
            raise ValueError(f"time_step must be positive, got {dt}.")
        return replace(
            self,
            time_step=dt,
            connections=tuple(Connection(c.source, c.target, c.rate * dt)
                              for c in self.connections),
            outlets=tuple(Outlet(o.compartment, o.rate * dt) for o in self.outlets),
        )

    def continuous(self) -> CompartmentNetwork:
        """The continuous-time network with rates ``fraction / time_step`` per unit time."""
        if self.time_step is None:
            return self
        dt = self.time_step
        return replace(
            self,
            time_step=None,
            connections=tuple(Connection(c.source, c.target, c.rate / dt)
                              for c in self.connections),
            outlets=tuple(Outlet(o.compartment, o.rate / dt) for o in self.outlets),
        )

    def steady_state_holdups(self, total_holdup: float = 1.0) -> np.ndarray:
        """Holdups that stay constant under the network's flows, scaled to `total_holdup`.

        For an open network: the steady state of ``dm/dt = K m + feed``; for a closed one:
        the stationary distribution (null vector of ``K``). Exchanges then keep every
        compartment's size fixed, as the particle model requires.

        **Returns:**

        Array of holdups (same unit as `total_holdup`).
        """
        q = self.connection_matrix()
        generator = q.T - np.diag(q.sum(axis=1) + self.outflow_vector())
        if not self.is_closed and self.inlets:
            if np.all(self.outflow_vector() == 0):
                raise ValueError("An open network without outflow has no steady state.")
            state = np.linalg.solve(generator, -self.feed_split)
        else:
            _, singular, vt = np.linalg.svd(generator)
            if singular.size > 1 and singular[-2] < 1e-12 * max(singular[0], 1.0):
                raise ValueError("The closed network is not connected: no unique steady state.")
            state = vt[-1]
            state = state * np.sign(state.sum())
        state = np.where(np.abs(state) < 1e-15 * np.abs(state).max(), 0.0, state)
        if np.any(state < 0):
            raise ValueError("The network has no non-negative steady state.")
        return state / state.sum() * float(total_holdup)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """A JSON-ready dictionary (the file format of `to_json`)."""
        return {
            "format": "axialmix.network",
            "version": _FORMAT_VERSION,
            "description": self.description,
            "time_step": self.time_step,
            "compartments": [
                {"name": name} if self.holdups is None else {"name": name, "holdup": h}
                for name, h in zip(
                    self.compartments,
                    self.holdups or [None] * self.n_compartments,
                    strict=True,
                )
            ],
            "connections": [
                {"source": c.source, "target": c.target, "rate": c.rate} for c in self.connections
            ],
            "inlets": [{"compartment": i.compartment, "fraction": i.fraction} for i in self.inlets],
            "outlets": [{"compartment": o.compartment, "rate": o.rate} for o in self.outlets],
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> CompartmentNetwork:
        """Build a network from the dictionary layout written by `to_dict`."""
        if not isinstance(data, Mapping):
            raise ValueError("A network file must hold a table/object at the top level.")
        unknown = set(data) - {
            "format", "version", "description", "time_step",
            "compartments", "connections", "inlets", "outlets",
        }
        if unknown:
            raise ValueError(f"Unknown network keys: {', '.join(sorted(unknown))}.")
        if "compartments" not in data:
            raise ValueError("A network file needs a 'compartments' list.")
        entries = data["compartments"]
        names = []
        holdups: list[float] = []
        for entry in entries:
            if isinstance(entry, str):
                names.append(entry)
                continue
            names.append(entry["name"])
            if "holdup" in entry and entry["holdup"] is not None:
                holdups.append(entry["holdup"])
        if holdups and len(holdups) != len(names):
            raise ValueError("Give a holdup for every compartment or for none.")
        try:
            return cls(
                compartments=names,
                connections=data.get("connections", []),
                inlets=data.get("inlets", []),
                outlets=data.get("outlets", []),
                holdups=holdups or None,
                time_step=data.get("time_step"),
                description=data.get("description", ""),
            )
        except KeyError as err:
            raise ValueError(f"Missing key {err.args[0]!r} in a network file entry.") from None

    def to_json(self, path: str | Path | None = None) -> str:
        """Write the network as human-editable JSON (to `path` if given) and return the text."""
        text = json.dumps(self.to_dict(), indent=2) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_json(cls, source: str | Path) -> CompartmentNetwork:
        """Read a network from a JSON file path or a JSON string."""
        text = str(source)
        if not text.lstrip().startswith("{"):
            path = Path(source)
            text = path.read_text()
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"Network JSON is not valid: {err}.") from None
        return cls.from_dict(data)

    @classmethod
    def from_toml(cls, path: str | Path) -> CompartmentNetwork:
        """Read a network from a TOML file with the JSON layout (``[[compartments]]`` tables).

        A continuous network omits ``time_step`` (TOML has no null).
        """
        import tomllib

        with open(path, "rb") as handle:
            try:
                data = tomllib.load(handle)
            except tomllib.TOMLDecodeError as err:
                raise ValueError(f"Network TOML in {path} is not valid: {err}.") from None
        return cls.from_dict(data)
