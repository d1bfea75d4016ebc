"""Compartment networks learned from recorded cell sequences (transition counts at a lag).

A recorded run gives, for every particle, the cell it is in at every frame: a set of discrete
trajectories. Counting the transitions ``i -> j`` between frames ``lag`` apart (a sliding
window, deeptime's :class:`~deeptime.markov.TransitionCountEstimator`) gives the row-stochastic
transition matrix ``T(tau)``, ``T_ij = C_ij / sum_j C_ij``; the continuous-time network whose
transition matrix at the lag is ``T(tau)`` has the rate matrix ``Q = log T(tau) / tau``
(``Q_ij``, 1/s, the fraction of cell i moving to j per second: ``k_ij`` of MODELS.md §3).
Where the matrix logarithm has small negative off-diagonal entries (sampling noise, or a
lag at which the motion is not Markov) they are set to zero and the diagonal is rebalanced;
:attr:`LearnedNetwork.clipped` says how much rate that removed.

Uncertainty: a block bootstrap. The frames are cut into blocks (impeller revolutions for a
DEM run); each replicate sums the count matrices of blocks drawn with replacement and gives
a rate matrix; the 2.5 and 97.5 percentiles of the replicates are the 95 % interval of each
rate. Blocks as long as a revolution keep the correlation of the motion within a block.

Markov test (:func:`markov_test`): implied time scales ``-tau / log |lambda_k(T(tau))|``
should not depend on the lag once the lag is long enough for the chain to be Markov, and
the Chapman–Kolmogorov test compares ``T(tau)^k`` with ``T(k tau)`` estimated directly.

Cell size (:func:`cell_length_limit`): a chain of cells of length ``dx`` carried at velocity
``v`` has its own numerical dispersion of about ``|v| dx / 2``; keeping it below the
dispersion ``D_z`` to be represented needs ``dx <= 2 D_z / |v|``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from axialmix._progress import iterate

__all__ = [
    "LearnedNetwork",
    "MarkovTest",
    "axial_cells",
    "block_count_matrices",
    "cell_length_limit",
    "count_matrix",
    "count_occupancy",
    "equal_occupancy_sectors",
    "learn_network",
    "markov_test",
    "observed_edges",
    "rates_by_likelihood",
    "rates_from_counts",
    "sequences_from_particle_events",
]


def axial_cells(
    z: np.ndarray,
    length: float,
    n_cells: int,
    *,
    periodic: bool = False,
    radius: np.ndarray | None = None,
    vessel_radius: float | None = None,
    n_radial: int = 1,
    angle: np.ndarray | None = None,
    sector_edges: np.ndarray | None = None,
) -> np.ndarray:
    """Cell index of every sample: equal axial cells, optionally × radial rings × angular sectors.

    **Arguments:**

    - `z`: axial coordinates, m, any shape.
    - `length`: axial length divided into `n_cells` equal cells, m.
    - `periodic`: wrap ``z`` into ``[0, length)`` first (a periodic section).
    - `radius`, `vessel_radius`, `n_radial`: distance from the axis (m, same shape as `z`),
      the vessel radius, and the number of rings of equal cross-section area.
    - `angle`, `sector_edges`: the angle of every sample around the axis in the fixed (lab)
      frame, rad, in ``[-pi, pi]`` (``atan2(y, x)``; same shape as `z`), and the increasing
      edges of the angular sectors, rad, from ``-pi`` to ``pi`` (``k + 1`` edges for ``k``
      sectors; :func:`equal_occupancy_sectors` places them where the bed is). In a bladed
      blender the bed rises with the blades on one side and falls back on the other: sectors
      tell the rising, resting and falling spheres apart, which move along the axis at
      different speeds.

    The cells of one axial layer are its ``n_radial × n_sectors`` sub-cells, and the index is
    ``(axial * n_radial + ring) * n_sectors + sector``: every axial layer is a block of
    consecutive indices (``index // (n_radial * n_sectors)`` is the axial cell).

    **Returns:** integer array of the shape of `z`; values outside ``[0, length)`` are clipped
    to the end cells (a closed vessel).

    **Raises:** ``ValueError`` for a bad cell count, rings without radii, or sectors without
    angles or with edges that do not rise from ``-pi`` to ``pi``.
    """
    if int(n_cells) != n_cells or n_cells < 1:
        raise ValueError(f"n_cells must be a positive whole number, got {n_cells}.")
    if int(n_radial) != n_radial or n_radial < 1:
        raise ValueError(f"n_radial must be a positive whole number, got {n_radial}.")
    z = np.asarray(z, dtype=float)
    if periodic:
        z = np.mod(z, length)
    cells = np.clip(np.floor(z / length * n_cells).astype(np.int64), 0, n_cells - 1)
    if n_radial > 1:
        if radius is None or vessel_radius is None:
            raise ValueError("radial cells need the radius of every sample and of the vessel.")
        rings = np.clip(
            np.floor((np.asarray(radius, float) / vessel_radius) ** 2 * n_radial).astype(np.int64),
            0, n_radial - 1,
        )
        cells = cells * n_radial + rings
    if sector_edges is not None:
        edges = np.asarray(sector_edges, dtype=float)
        if (edges.ndim != 1 or edges.size < 2 or not np.all(np.diff(edges) > 0)
                or not np.isclose(edges[0], -np.pi) or not np.isclose(edges[-1], np.pi)):
            raise ValueError("sector_edges must rise strictly from -pi to pi (rad).")
        if angle is None:
            raise ValueError("angular sectors need the angle of every sample.")
        n_sectors = edges.size - 1
        sectors = np.clip(np.searchsorted(edges, np.asarray(angle, float), side="right") - 1,
                          0, n_sectors - 1)
        cells = cells * n_sectors + sectors
    return cells


def equal_occupancy_sectors(angle: np.ndarray, n_sectors: int) -> np.ndarray:
    """Edges of `n_sectors` angular sectors that each hold the same share of the samples.

    A partly filled horizontal blender holds its bed in a fraction of the circle (and tilted
    by the blades): sectors of equal angle would leave most of them empty. These edges split
    the angles recorded (for example every sphere in every frame of the learning window) into
    equal shares; the outer edges are ``-pi`` and ``pi``, so every angle has a sector.

    **Arguments:** `angle`, rad, any shape (``atan2(y, x)`` around the axis); `n_sectors`.

    **Returns:** ``n_sectors + 1`` increasing edges, rad, for :func:`axial_cells`.

    **Raises:** ``ValueError`` when `n_sectors` is not a positive whole number or the angles
    do not allow that many distinct sectors.
    """
    if int(n_sectors) != n_sectors or n_sectors < 1:
        raise ValueError(f"n_sectors must be a positive whole number, got {n_sectors}.")
    angle = np.asarray(angle, dtype=float).ravel()
    angle = angle[np.isfinite(angle)]
    if angle.size == 0:
        raise ValueError("no finite angle to place sectors by.")
    edges = np.quantile(angle, np.linspace(0.0, 1.0, int(n_sectors) + 1))
    edges[0], edges[-1] = -np.pi, np.pi
    if not np.all(np.diff(edges) > 0):
        raise ValueError(f"the angles recorded do not fill {n_sectors} distinct sectors.")
    return edges


def _runs(sequences) -> list[np.ndarray]:
    """The recorded runs in `sequences`: one ``(frames, particles)`` array of cell indices,
    or a list or tuple of such arrays (several runs, or windows, of the same cells; their
    frame and particle counts may differ)."""
    parts = [sequences]
    if isinstance(sequences, (list, tuple)):
        if not sequences:
            raise ValueError("no cell sequences given.")
        # Arrays in a list are runs; a nested list of whole numbers is one array.
        if any(isinstance(part, np.ndarray) or np.ndim(part) == 2 for part in sequences):
            parts = list(sequences)
    runs = [np.asarray(part) for part in parts]
    for k, run in enumerate(runs):
        if run.ndim != 2:
            where = f" (run {k + 1} of {len(runs)})" if len(runs) > 1 else ""
            raise ValueError(f"cell sequences must be a (frames, particles) array{where}.")
    return runs


def _as_sequences(sequences) -> list[np.ndarray]:
    return [np.ascontiguousarray(run[:, i], dtype=np.int32)
            for run in _runs(sequences) for i in range(run.shape[1])]


def count_matrix(sequences: np.ndarray, n_states: int, lag: int) -> np.ndarray:
    """Transition counts ``C_ij`` between frames `lag` apart (sliding window), with deeptime.

    **Arguments:** `sequences` ``(frames, particles)`` cell indices, or a list of such arrays
    (several runs of the same cells: their counts add); `n_states` cells; `lag` in frames (at
    least 1).

    **Returns:** ``(n_states, n_states)`` float array of counts (row: from, column: to).
    """
    from deeptime.markov import TransitionCountEstimator

    if int(lag) != lag or lag < 1:
        raise ValueError(f"lag must be a positive whole number of frames, got {lag}.")
    frames = min(run.shape[0] for run in _runs(sequences))
    if frames <= lag:
        raise ValueError(f"a lag of {lag} frames needs more than {lag} frames, got {frames}.")
    estimator = TransitionCountEstimator(int(lag), "sliding", n_states=int(n_states))
    model = estimator.fit(_as_sequences(sequences)).fetch_model()
    return np.asarray(model.count_matrix, dtype=float)


def block_count_matrices(
    sequences: np.ndarray, n_states: int, lag: int, block_frames: int
) -> np.ndarray:
    """Count matrices of consecutive blocks of `block_frames` start frames each.

    Block b holds the transitions starting at frames ``b * block_frames`` to
    ``(b + 1) * block_frames - 1``; summed over blocks they give :func:`count_matrix` of the
    frames the blocks cover. Counted with NumPy in one pass (deeptime's estimator costs a
    call per block, 50 times slower here); the tests check the sum against deeptime. A list of
    runs of the same cells gives the blocks of each run in turn (each run at least 2 blocks).

    **Returns:** ``(blocks, n_states, n_states)`` float array.
    """
    runs = _runs(sequences)
    if len(runs) > 1:
        return np.concatenate([block_count_matrices(run, n_states, lag, block_frames)
                               for run in runs])
    sequences = np.asarray(runs[0], dtype=np.int64)
    starts = sequences.shape[0] - lag
    n_blocks = starts // int(block_frames)
    if n_blocks < 2:
        raise ValueError(
            f"{sequences.shape[0]} frames give {n_blocks} block(s) of {block_frames} frames at "
            f"lag {lag}; the bootstrap needs at least 2."
        )
    used = n_blocks * int(block_frames)
    pairs = sequences[:used] * n_states + sequences[lag: used + lag]
    block = np.repeat(np.arange(n_blocks), block_frames)[:, None]
    flat = np.bincount((block * n_states * n_states + pairs).ravel(),
                       minlength=n_blocks * n_states * n_states)
    return flat.reshape(n_blocks, n_states, n_states).astype(float)


#: Largest relative error of a matrix logarithm that is used, ``||exp(L) - T||_1 / ||T||_1``
#: for the real logarithm ``L`` scipy finds; a transition matrix whose logarithm misses it (a
#: singular or defective matrix, or one with negative eigenvalues: a lag at which some cell
#: is left for good) has no rate matrix.
LOG_TOLERANCE = 1e-8


def _matrix_log(matrices: np.ndarray) -> np.ndarray:
    # log T = V log(Lambda) V^-1 for a batch; scipy's logm where V is ill-conditioned. A
    # logarithm whose exponential misses T by more than LOG_TOLERANCE is NaN (not a number
    # that looks like a rate).
    values, vectors = np.linalg.eig(matrices)
    out = np.empty(matrices.shape, dtype=float)
    for k in range(matrices.shape[0]):
        if np.linalg.cond(vectors[k]) < 1e8 and np.all(np.abs(values[k]) > 1e-12):
            log = vectors[k] @ np.diag(np.log(values[k].astype(complex))) @ np.linalg.inv(
                vectors[k])
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # its accuracy is measured instead
                log = np.real(scipy.linalg.logm(matrices[k]))
                error = (np.linalg.norm(scipy.linalg.expm(log) - matrices[k], 1)
                         / np.linalg.norm(matrices[k], 1))
            if not (np.isfinite(error) and error <= LOG_TOLERANCE):
                log = np.full(matrices.shape[1:], np.nan)
        out[k] = np.real(log)
    return out


def rates_from_counts(counts: np.ndarray, lag_seconds: float) -> tuple[np.ndarray, float]:
    """Rate matrix ``Q = log T / tau`` from transition counts, negative rates clipped to zero.

    **Arguments:** `counts` ``(n, n)`` or a batch ``(m, n, n)``; `lag_seconds` ``tau``, s.

    **Returns:** ``(Q, clipped)``: ``Q`` of the shape of `counts`, in 1/s (rows sum to zero,
    off-diagonal entries non-negative), and the largest share of a cell's leaving rate removed
    by clipping. A cell never visited gets zero rates. A transition matrix whose logarithm
    cannot be computed to :data:`LOG_TOLERANCE` gives a rate matrix of NaN (and `clipped` is
    taken over the others).
    """
    counts = np.asarray(counts, dtype=float)
    single = counts.ndim == 2
    counts = counts[None] if single else counts
    n = counts.shape[-1]
    rows = counts.sum(axis=-1, keepdims=True)
    visited = rows[..., 0] > 0
    transition = np.where(rows > 0, counts / np.where(rows > 0, rows, 1), np.eye(n))
    rates = _matrix_log(transition) / lag_seconds
    off = ~np.eye(n, dtype=bool)
    negative = np.where(off & (rates < 0), -rates, 0).sum(axis=-1)
    rates = np.where(off, np.maximum(rates, 0), 0)
    leaving = rates.sum(axis=-1)
    rates[..., np.arange(n), np.arange(n)] = -leaving
    rates[~visited] = 0
    share = negative / np.maximum(leaving + negative, 1e-300)
    clipped = float(np.nan_to_num(share[visited], nan=0.0).max(initial=0.0))
    return (rates[0] if single else rates), clipped


def observed_edges(sequences: np.ndarray, n_states: int) -> np.ndarray:
    """The connections a network of these cells can have: pairs ``(i, j)``, ``i != j``, seen
    as consecutive cells of one particle from one frame to the next (neighbours in space:
    between two frames a particle crosses into an adjacent cell, not across the vessel).
    `sequences`: ``(frames, particles)`` cell indices, or a list of such arrays (the
    connections seen in any of them).

    **Returns:** ``(m, 2)`` integer array of ``(from, to)`` cells.
    """
    counts = count_matrix(sequences, n_states, 1)
    i, j = np.nonzero((counts > 0) & ~np.eye(n_states, dtype=bool))
    return np.stack([i, j], axis=1)


def _likelihood_program(n: int, edges: np.ndarray, lag_seconds: float):
    """``(theta, counts) -> (negative log-likelihood per count, gradient)`` of the network
    with rates ``exp(theta)`` on `edges` (jitted; JAX)."""
    import jax
    import jax.numpy as jnp

    source, target = jnp.asarray(edges[:, 0]), jnp.asarray(edges[:, 1])

    def negative_log_likelihood(theta, counts):
        rates = jnp.zeros((n, n)).at[source, target].set(jnp.exp(theta))
        generator = rates - jnp.diag(rates.sum(axis=1))
        transition = jax.scipy.linalg.expm(generator * lag_seconds)
        log_p = jnp.log(jnp.clip(transition, 1e-300, None))
        return -jnp.sum(counts * log_p) / jnp.maximum(jnp.sum(counts), 1.0)

    return jax.jit(jax.value_and_grad(negative_log_likelihood))


def count_occupancy(counts: np.ndarray) -> np.ndarray:
    """Share of the particles in each cell over the frames the counts cover: the mean of the
    counts' start occupancy (row sums) and end occupancy (column sums), normalised to 1.

    **Arguments:** `counts` ``(n, n)`` or a batch ``(m, n, n)``.

    **Returns:** ``(n,)`` or ``(m, n)`` shares (dimensionless, summing to 1).
    """
    counts = np.asarray(counts, dtype=float)
    held = counts.sum(axis=-1) + counts.sum(axis=-2)
    return held / np.maximum(held.sum(axis=-1, keepdims=True), 1e-300)


#: Largest violation of the steady-state condition ``pi Q = 0`` of the ``"stationary"``
#: estimator, ``max_j |(pi Q)_j| / sum_i pi_i |Q_ii|``; a fit that misses it gives NaN rates.
STATIONARY_TOLERANCE = 1e-8


def _stationary_program(n: int, edges: np.ndarray, lag_seconds: float):
    """``(theta, counts, occupancy) -> (negative log-likelihood per count, gradient)`` of
    the network with the jump rates ``exp(theta)`` on `edges`, each cell's leaving rates
    scaled so that `occupancy` is its steady state (jitted; JAX).

    Scaling row i of a rate matrix by ``x_i > 0`` (a change of clock in cell i) keeps where a
    particle goes next and changes the steady state from ``pi`` to ``pi_i / x_i``
    (normalised): with ``x = pi(theta) / occupancy`` the network holds `occupancy`, and every
    network that does is reached this way (its own rates give ``x = 1``), so maximising over
    ``theta`` is the likelihood maximised subject to the steady state.
    """
    import jax
    import jax.numpy as jnp

    source, target = jnp.asarray(edges[:, 0]), jnp.asarray(edges[:, 1])
    unit = jnp.zeros(n).at[n - 1].set(1.0)

    def negative_log_likelihood(theta, counts, occupancy):
        rates = jnp.zeros((n, n)).at[source, target].set(jnp.exp(theta))
        generator = rates - jnp.diag(rates.sum(axis=1))
        # pi Q = 0 with sum pi = 1: the last balance equation replaced by the normalisation.
        system = generator.T.at[n - 1].set(1.0)
        steady = jnp.linalg.solve(system, unit)
        generator = (steady / occupancy)[:, None] * generator
        transition = jax.scipy.linalg.expm(generator * lag_seconds)
        log_p = jnp.log(jnp.clip(transition, 1e-300, None))
        return -jnp.sum(counts * log_p) / jnp.maximum(jnp.sum(counts), 1.0)

    return jax.jit(jax.value_and_grad(negative_log_likelihood))


def _held_rates(rates: np.ndarray, occupancy: np.ndarray) -> np.ndarray | None:
    """`rates` with row i scaled by ``pi_i / occupancy_i`` (``pi`` their steady state):
    the network that holds `occupancy`; ``None`` where it misses it by more than
    :data:`STATIONARY_TOLERANCE` (a network not connected both ways)."""
    with np.errstate(all="ignore"):
        steady = _stationary(rates)
        held = (steady / occupancy)[:, None] * rates
        scale = float(occupancy @ np.abs(np.diag(held)))
        miss = float(np.abs(occupancy @ held).max()) / scale
    if not (np.all(steady > 0) and np.isfinite(miss) and miss <= STATIONARY_TOLERANCE):
        return None
    return held


def rates_by_likelihood(counts: np.ndarray, lag_seconds: float, edges: np.ndarray,
                        start: np.ndarray | None = None, *,
                        stationary: bool = False) -> np.ndarray:
    """Rate matrix of largest likelihood of the transition counts, with rates on `edges` only.

    The network's transition matrix at the lag is ``P = expm(Q tau)``; the counts' log
    likelihood is ``sum_ij C_ij log P_ij`` (a multinomial for each row). Maximised over the
    rates of the given connections (``Q_ij = exp(theta_ij) > 0``, L-BFGS with the exact
    gradient), it is always a valid network, whatever the lag, where ``log T / tau`` can need
    negative rates (a lag at which the motion is not Markov, or one over which the drift
    carries a particle across several cells: the matrix logarithm then takes the wrong
    branch).

    The row-by-row likelihood says nothing of where the particles are: the network's own
    steady state (``pi Q = 0``) can differ from the occupancy the counts were taken in when
    the motion is not Markov in these cells, and with it the network's long-time drift (on a
    DEM section of lanes moving at different speeds, 6-12 % too fast). With `stationary`, the
    likelihood is maximised subject to the network holding the counts' occupancy
    (:func:`count_occupancy`) as its steady state, to :data:`STATIONARY_TOLERANCE`.

    **Arguments:** `counts` ``(n, n)`` or a batch ``(m, n, n)``; `lag_seconds` ``tau``, s;
    `edges` ``(k, 2)`` allowed ``(from, to)`` pairs (:func:`observed_edges`); `start` rate
    matrix (1/s) to start from (default: :func:`rates_from_counts`'s, or the first-order
    ``T_ij / tau`` where the counts' matrix has no logarithm, on the edges, each at least a
    thousandth of their mean); `stationary` constrain the steady state to the occupancy.

    **Returns:** ``Q`` of the shape of `counts`, 1/s (rows sum to zero); with `stationary`,
    NaN for a count matrix with a cell that holds no particle, or whose constrained fit
    misses :data:`STATIONARY_TOLERANCE`.
    """
    from scipy.optimize import minimize

    counts = np.asarray(counts, dtype=float)
    single = counts.ndim == 2
    counts = counts[None] if single else counts
    n = counts.shape[-1]
    edges = np.asarray(edges, dtype=int).reshape(-1, 2)
    program = (_stationary_program if stationary else _likelihood_program)(
        n, edges, float(lag_seconds))  # jitted: compiled at its first call
    out = np.zeros(counts.shape)
    # Bootstrap replicates are fitted one after another (minutes for hundreds of cells):
    # a progress bar on a terminal.
    replicates = iterate(counts, description="likelihood fits", unit="fit",
                         enabled=None if counts.shape[0] > 1 else False)
    for k, c in enumerate(replicates):
        arguments = (c,)
        if stationary:
            occupancy = count_occupancy(c)
            if np.any(occupancy <= 0):
                out[k] = np.nan  # a cell without particles cannot be held
                continue
            arguments = (c, occupancy)
        guess = rates_from_counts(c, lag_seconds)[0] if start is None else np.asarray(start)
        if not np.isfinite(guess).all():  # no matrix logarithm: first-order rates T_ij / tau
            guess = _transition(c) / lag_seconds
        first = guess[edges[:, 0], edges[:, 1]]
        floor = 1e-3 * max(float(np.mean(first[first > 0])) if np.any(first > 0) else 0.0,
                           1e-6 / lag_seconds)
        theta0 = np.log(np.maximum(first, floor))

        def objective(theta, arguments=arguments):
            value, gradient = program(theta, *arguments)
            return float(value), np.asarray(gradient, float)

        best = minimize(objective, theta0, jac=True, method="L-BFGS-B",
                        options={"maxiter": 2000, "ftol": 1e-13, "gtol": 1e-9})
        rates = np.zeros((n, n))
        rates[edges[:, 0], edges[:, 1]] = np.exp(best.x)
        rates[np.arange(n), np.arange(n)] = -rates.sum(axis=1)
        if stationary:
            rates = _held_rates(rates, occupancy)
            if rates is None:
                out[k] = np.nan
                continue
        out[k] = rates
    return out[0] if single else out


def _largest_connected_set(counts: np.ndarray) -> np.ndarray:
    """Indices of the largest set of states connected both ways by the counts."""
    from scipy.sparse.csgraph import connected_components

    _, labels = connected_components(counts > 0, directed=True, connection="strong")
    largest = np.argmax(np.bincount(labels))
    return np.flatnonzero(labels == largest)


def _stationary(generator: np.ndarray) -> np.ndarray:
    """Stationary distribution ``pi`` of an irreducible rate matrix (``pi Q = 0``,
    ``sum pi = 1``)."""
    n = generator.shape[0]
    system = np.vstack([generator.T, np.ones((1, n))])
    target = np.zeros(n + 1)
    target[-1] = 1.0
    pi = np.linalg.lstsq(system, target, rcond=None)[0]
    pi = np.clip(pi, 0.0, None)
    return pi / pi.sum()


@dataclass(frozen=True, eq=False)
class LearnedNetwork:
    """A compartment network learned from cell sequences, with bootstrap uncertainty.

    **Fields:**

    - `names`: cell names.
    - `rates`: ``(n, n)`` rate matrix ``Q`` from all frames, 1/s (``Q_ij``: i -> j).
    - `lower`, `upper`: 95 % block-bootstrap interval of every rate, 1/s.
    - `replicates`: ``(bootstrap, n, n)`` rate matrices of the replicates, 1/s.
    - `counts`: ``(n, n)`` transition counts at the lag.
    - `lag_seconds`: the lag ``tau``, s; `lag_frames` the same in frames.
    - `holdups`: mean number of particles in each cell.
    - `centres`: axial centre of each cell, m (for the equivalent ADM), or ``None``.
    - `period`: axial period, m, for a periodic section (distances wrap), else ``None``.
    - `clipped`: largest share of a cell's leaving rate removed by clipping negative rates.
    - `blocks`: number of bootstrap blocks; `block_seconds` their length, s.
    - `failed`: bootstrap replicates left out because their transition matrix has no
      accurate logarithm (``"logm"`` estimator: a block resample in which a cell is left for
      good); `replicates` holds the others. When more than :data:`FAILED_SHARE` of the
      replicates failed, or fewer than :data:`MIN_REPLICATES` are left, the intervals
      cannot be given: `lower`, `upper` and :meth:`transport_interval` are NaN.
    """

    names: tuple[str, ...]
    rates: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    replicates: np.ndarray
    counts: np.ndarray
    lag_seconds: float
    lag_frames: int
    holdups: np.ndarray
    centres: np.ndarray | None
    period: float | None
    clipped: float
    blocks: int
    block_seconds: float
    failed: int = 0

    @property
    def n_cells(self) -> int:
        """Number of cells."""
        return len(self.names)

    def connections(self, minimum_rate: float = 0.0) -> list[tuple[int, int]]:
        """Pairs ``(i, j)``, ``i != j``, whose learned rate is above `minimum_rate` (1/s)."""
        i, j = np.nonzero((self.rates > minimum_rate) & ~np.eye(self.n_cells, dtype=bool))
        return list(zip(i.tolist(), j.tolist(), strict=True))

    def network(self, minimum_rate: float = 0.0, description: str = ""):
        """The learned network as a closed :class:`axialmix.network.CompartmentNetwork`.

        Rates in 1/s (continuous time), hold-ups the mean occupancies (particles); only
        connections with a rate above `minimum_rate` are kept.
        """
        from ..network import CompartmentNetwork, Connection

        return CompartmentNetwork(
            compartments=self.names,
            connections=[
                Connection(self.names[i], self.names[j], float(self.rates[i, j]))
                for i, j in self.connections(minimum_rate)
            ],
            holdups=[float(max(h, 1e-9)) for h in self.holdups],
            description=description
            or f"learned from transition counts at lag {self.lag_seconds:.6g} s",
        )

    def _jumps(self) -> np.ndarray:
        if self.centres is None:
            raise ValueError("the cells have no axial centres; the equivalent ADM needs them.")
        jumps = self.centres[None, :] - self.centres[:, None]
        if self.period is not None:
            jumps = (jumps + self.period / 2) % self.period - self.period / 2
        return jumps

    def transport(self, rates: np.ndarray | None = None) -> tuple[float, float]:
        """The network's equivalent ADM: ``(v, D_z)`` in m/s and m²/s.

        With ``dz_ij`` the axial jump from cell i to j and ``b_i = sum_j Q_ij dz_ij`` the
        drift out of cell i:

        * **periodic section** (`period` set): the long-time drift and dispersion of a
          particle following the network, unwrapped along the axis (the central limit of its
          displacement): ``v = sum_i pi_i b_i`` with ``pi`` the network's stationary
          distribution, and ``D_z = 1/2 sum_i pi_i sum_j Q_ij (dz_ij + chi_j - chi_i)²``
          where ``sum_j Q_ij chi_j = v - b_i``. The corrector ``chi`` carries what a
          cell-to-cell difference of drift adds over time: cells of one axial slice that
          move at different speeds (radial rings) give Taylor dispersion, two lanes of
          speeds ``v_1, v_2`` exchanging at rate ``k`` each way add ``(v_1 - v_2)² / (8 k)``.
          For a chain of neighbours with the same rates everywhere ``chi = 0`` and this is
          ``v = (a - b) dx``, ``D_z = (a + b) dx² / 2``, as
          :func:`axialmix.network.backflow_chain_transport`.
        * **closed vessel**: the occupancy-weighted means of ``b_i`` and of
          ``sum_j Q_ij dz_ij² / 2`` (the local drift and dispersion; a closed vessel has no
          long-time drift).
        """
        rates = self.rates if rates is None else np.asarray(rates, float)
        jumps = self._jumps()
        off = np.where(np.eye(self.n_cells, dtype=bool), 0, rates)
        drift = (off * jumps).sum(axis=1)
        if self.period is None:
            weights = self.holdups / self.holdups.sum()
            return float(weights @ drift), float(weights @ (off * jumps**2).sum(axis=1) / 2)
        # On the cells connected both ways (a cell never entered has no say).
        keep = _largest_connected_set(off)
        off, jumps, drift = off[np.ix_(keep, keep)], jumps[np.ix_(keep, keep)], drift[keep]
        generator = off - np.diag(off.sum(axis=1))
        stationary = _stationary(generator)
        v = float(stationary @ drift)
        corrector = np.linalg.lstsq(generator, v - drift, rcond=None)[0]
        moved = jumps + corrector[None, :] - corrector[:, None]
        return v, float(stationary @ (off * moved**2).sum(axis=1) / 2)

    def transport_interval(self) -> tuple[np.ndarray, np.ndarray]:
        """95 % bootstrap intervals of ``v`` (m/s) and ``D_z`` (m²/s): two ``(2,)`` arrays."""
        if not np.isfinite(self.lower).all():
            return np.full(2, np.nan), np.full(2, np.nan)
        values = np.array([self.transport(r) for r in self.replicates])
        return (np.percentile(values[:, 0], [2.5, 97.5]), np.percentile(values[:, 1], [2.5, 97.5]))


#: Largest share of bootstrap replicates that may fail (no accurate matrix logarithm) for the
#: intervals still to be given from the others.
FAILED_SHARE = 0.05


#: Fewest bootstrap replicates that give 95 % intervals. With fewer, the 2.5 % and 97.5 %
#: percentiles are interpolated between the two or three most extreme replicates and say
#: nothing of the rates' spread (2 replicates gave v in [-21.17, -21.06] mm/s around an
#: estimate of -20.99); the rates are then given without intervals (NaN).
MIN_REPLICATES = 20


#: The estimators of :func:`learn_network`.
ESTIMATORS = ("logm", "likelihood", "stationary")


def learn_network(
    sequences: np.ndarray,
    n_states: int,
    frame_interval: float,
    lag: int,
    block_frames: int,
    *,
    n_bootstrap: int = 200,
    seed: int = 0,
    names: tuple[str, ...] | None = None,
    centres: np.ndarray | None = None,
    period: float | None = None,
    estimator: str = "logm",
) -> LearnedNetwork:
    """Learn a continuous-time network from cell sequences, with block-bootstrap intervals.

    **Arguments:**

    - `sequences`: ``(frames, particles)`` cell indices (0 to ``n_states - 1``), or a list
      of such arrays: several runs (or windows) of the same cells, learned as one network
      (their counts add; the bootstrap draws from the blocks of every run; each run must
      hold at least two blocks). Several independent runs give the section's network
      rather than one window's: the slow fluctuations a window shares (a drift that wanders
      by a tenth over seconds) average out; it need not predict any one run's later frames
      better.
    - `n_states`: number of cells.
    - `frame_interval`: time between frames, s.
    - `lag`: lag in frames; ``tau = lag * frame_interval``.
    - `block_frames`: bootstrap block length in frames (an impeller revolution for DEM).
    - `n_bootstrap`: bootstrap replicates; `seed` their random seed. 0 (or any number below
      :data:`MIN_REPLICATES`): the rates alone, without intervals (`lower` and `upper` NaN).
    - `names`, `centres`, `period`: cell names (default ``C1``...), axial centres (m) and the
      axial period of a periodic section (m), for :meth:`LearnedNetwork.transport`.
    - `estimator`: ``"logm"``, ``Q = log T / tau`` with negative rates clipped
      (:func:`rates_from_counts`), or ``"likelihood"``, the rates of largest likelihood on
      the connections seen from frame to frame (:func:`rates_by_likelihood`: a valid network
      at any lag; each bootstrap replicate is refitted, starting from the whole run's rates),
      or ``"stationary"``, the same with the network's steady state held at the occupancy of
      the counts (``stationary=True``: the steady state that weights the network's
      long-time drift is then where the particles were in the counted frames, not one the
      fit is free to choose; each replicate at its own occupancy).

    **Returns:** a :class:`LearnedNetwork` (`clipped` is 0 for the likelihood estimator;
    `failed` counts the replicates left out of the intervals).

    **Raises:** ``ValueError`` when, with ``"logm"``, the whole run's transition matrix has no
    accurate logarithm (:data:`LOG_TOLERANCE`), or, with ``"stationary"``, when the whole
    run's constrained fit does not converge (:data:`STATIONARY_TOLERANCE`).
    """
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {', '.join(map(repr, ESTIMATORS))}, "
                         f"got {estimator!r}.")
    runs = _runs(sequences)
    if any(run.size and (run.min() < 0 or run.max() >= n_states) for run in runs):
        raise ValueError(f"cell indices must lie in 0..{n_states - 1}.")
    tau = lag * float(frame_interval)
    blocks = block_count_matrices(runs, n_states, lag, block_frames)
    total = blocks.sum(axis=0)
    rng = np.random.default_rng(seed)
    if int(n_bootstrap) != n_bootstrap or n_bootstrap < 0:
        raise ValueError(f"n_bootstrap must be a whole number >= 0, got {n_bootstrap}.")
    n_bootstrap = int(n_bootstrap)
    draws = rng.integers(0, blocks.shape[0], size=(n_bootstrap, blocks.shape[0]))
    weights = np.zeros((n_bootstrap, blocks.shape[0]), dtype=np.int64)
    for row, d in zip(weights, draws, strict=True):
        row[:] = np.bincount(d, minlength=blocks.shape[0])
    resampled = np.einsum("rb,bij->rij", weights, blocks)
    if estimator == "logm":
        rates, clipped = rates_from_counts(total, tau)
        if not np.isfinite(rates).all():
            raise ValueError(
                f"the transition matrix at lag {tau:g} s has no accurate real matrix logarithm "
                "(no rate matrix gives it at this lag): use a shorter lag or "
                "estimator='likelihood'.")
        replicates = (rates_from_counts(resampled, tau)[0] if n_bootstrap
                      else np.zeros((0, n_states, n_states)))
    else:
        edges = observed_edges(runs, n_states)
        stationary = estimator == "stationary"
        rates, clipped = rates_by_likelihood(total, tau, edges, stationary=stationary), 0.0
        if not np.isfinite(rates).all():
            empty = np.flatnonzero(count_occupancy(total) <= 0)
            why = (f"cell(s) {', '.join(str(i) for i in empty[:5])} hold no particle in the "
                   "counted frames" if empty.size else
                   f"the fit did not meet it to {STATIONARY_TOLERANCE:g} at lag {tau:g} s")
            raise ValueError(
                f"no network holds the occupancy of the counts as its steady state ({why}): "
                "use estimator='likelihood'.")
        replicates = (rates_by_likelihood(resampled, tau, edges, start=rates,
                                          stationary=stationary) if n_bootstrap
                      else np.zeros((0, n_states, n_states)))
    usable = np.isfinite(replicates).all(axis=(1, 2))
    failed = int(n_bootstrap - usable.sum())
    replicates = replicates[usable]
    if len(replicates) < MIN_REPLICATES or failed > FAILED_SHARE * n_bootstrap:
        lower = upper = np.full(rates.shape, np.nan)
    else:
        lower, upper = np.percentile(replicates, [2.5, 97.5], axis=0)
    holdups = (sum(np.bincount(run.ravel(), minlength=n_states) for run in runs)
               / sum(run.shape[0] for run in runs))
    return LearnedNetwork(
        names=tuple(names) if names is not None else tuple(f"C{i + 1}" for i in range(n_states)),
        rates=rates, lower=lower, upper=upper, replicates=replicates, counts=total,
        lag_seconds=tau, lag_frames=int(lag), holdups=holdups,
        centres=None if centres is None else np.asarray(centres, float),
        period=period, clipped=clipped, blocks=int(blocks.shape[0]),
        block_seconds=block_frames * float(frame_interval), failed=failed,
    )


@dataclass(frozen=True)
class MarkovTest:
    """Implied time scales over lags and a Chapman–Kolmogorov comparison.

    **Fields:**

    - `lags_seconds`: the lags tested, s.
    - `timescales`: ``(lags, k)`` the k slowest implied time scales at each lag, s.
    - `ck_steps`: multiples ``k`` of the base lag compared.
    - `ck_error`: ``max_ij |T(tau)^k - T(k tau)|_ij`` for each multiple (probability).
    - `ck_sampling`: the same maximum for two halves of the particles at lag ``k tau``
      (the sampling noise the CK error is to be judged against).
    """

    lags_seconds: np.ndarray
    timescales: np.ndarray
    ck_steps: np.ndarray
    ck_error: np.ndarray
    ck_sampling: np.ndarray

    def report(self) -> str:
        """The test as text."""
        lines = ["lag (s)   implied time scales (s)"]
        for lag, ts in zip(self.lags_seconds, self.timescales, strict=True):
            lines.append(f"{lag:7.3f}   " + "  ".join(f"{t:8.3f}" for t in ts))
        lines.append("Chapman-Kolmogorov: k  max|T(tau)^k - T(k tau)|  sampling (two halves)")
        for k, e, s in zip(self.ck_steps, self.ck_error, self.ck_sampling, strict=True):
            lines.append(f"                    {k:2d}  {e:.4f}                    {s:.4f}")
        return "\n".join(lines)


def _transition(counts: np.ndarray) -> np.ndarray:
    rows = counts.sum(axis=1, keepdims=True)
    return np.where(rows > 0, counts / np.where(rows > 0, rows, 1), np.eye(counts.shape[0]))


def markov_test(
    sequences: np.ndarray,
    n_states: int,
    frame_interval: float,
    lags: tuple[int, ...],
    *,
    base_lag: int | None = None,
    ck_steps: tuple[int, ...] = (2, 4, 8),
    n_timescales: int = 3,
) -> MarkovTest:
    """Implied time scales at several lags and a Chapman–Kolmogorov test (deeptime).

    **Arguments:**

    - `sequences`, `n_states`, `frame_interval`: as :func:`learn_network` (one run, or a
      list of runs of the same cells, tested together).
    - `lags`: lags in frames for the implied time scales.
    - `base_lag`: the lag the CK test propagates (default the first of `lags`).
    - `ck_steps`: multiples of the base lag compared.
    - `n_timescales`: how many of the slowest time scales to report.

    The time scales are those of the largest set of cells connected both ways at each lag,
    the Chapman–Kolmogorov test that of the base lag (cells no sphere visits, such as a ring
    inside the shaft's radius, have no transition matrix row and are left out).

    **Returns:** a :class:`MarkovTest`.
    """
    from deeptime.markov.msm import MarkovStateModel

    sequences = _runs(sequences)
    scales = []
    for lag in lags:
        counts = count_matrix(sequences, n_states, lag)
        keep = _largest_connected_set(counts)
        model = MarkovStateModel(_transition(counts[np.ix_(keep, keep)]), lagtime=int(lag))
        with warnings.catch_warnings():
            # A chain with drift is not reversible: its eigenvalues come in complex pairs,
            # and the time scales are those of their moduli (what deeptime warns about).
            warnings.simplefilter("ignore")
            ts = np.asarray(model.timescales(k=n_timescales), float) * frame_interval
        scales.append(ts)
    base = int(base_lag or lags[0])
    counts = count_matrix(sequences, n_states, base)
    keep = np.ix_(*(2 * (_largest_connected_set(counts),)))
    t_base = _transition(counts[keep])
    # The sampling noise from two halves of the spheres (of every run).
    first = [run[:, :run.shape[1] // 2] for run in sequences]
    second = [run[:, run.shape[1] // 2:] for run in sequences]
    errors, noise = [], []
    for k in ck_steps:
        direct = _transition(count_matrix(sequences, n_states, base * k)[keep])
        errors.append(np.abs(np.linalg.matrix_power(t_base, k) - direct).max())
        a = _transition(count_matrix(first, n_states, base * k)[keep])
        b = _transition(count_matrix(second, n_states, base * k)[keep])
        noise.append(np.abs(a - b).max() / 2)  # each half is sqrt(2) noisier than the whole
    return MarkovTest(
        lags_seconds=np.asarray(lags, float) * frame_interval,
        timescales=np.array(scales),
        ck_steps=np.asarray(ck_steps),
        ck_error=np.array(errors),
        ck_sampling=np.array(noise),
    )


def cell_length_limit(velocity: float, dispersion: float) -> float:
    """Longest cell whose chain dispersion ``|v| dx / 2`` stays below ``D_z``: ``2 D_z / |v|``, m.

    **Arguments:** `velocity` ``v`` (m/s), `dispersion` ``D_z`` (m²/s).
    """
    if velocity == 0:
        return float("inf")
    return 2 * float(dispersion) / abs(float(velocity))


def sequences_from_particle_events(result, species: int) -> np.ndarray:
    """Compartment of every particle of a tracked species at every step of a particle run.

    **Arguments:** `result`: an identity-engine :class:`axialmix.particles.SimulationResult`
    of a batch network (no feed) with `species` tracked; `species`: that species.

    **Returns:** ``(steps + 1, particles)`` integer array: row t is where each particle of the
    species is after t steps (particles in the order of their numbers).
    """
    network = result.network
    if network.is_continuous:
        raise ValueError("cell sequences need a batch network (particles neither fed nor lost).")
    counts0 = np.asarray(result.counts[0])
    offsets = np.concatenate([[0], np.cumsum(network.holdups)])
    n_species = counts0.shape[1]
    # Initial numbering (the identity engine): compartment by compartment, species in order.
    starts = offsets[:-1] + counts0[:, :species].sum(axis=1)
    numbers = np.concatenate([
        np.arange(s, s + c) for s, c in zip(starts, counts0[:, species], strict=True)
    ]).astype(np.int64)
    initial = np.repeat(np.arange(network.n_compartments), counts0[:, species])
    del n_species
    steps = result.steps_completed
    events = result.events
    events = events[events[:, 3] >= 0]
    index = np.searchsorted(numbers, events[:, 0])
    if np.any(numbers[np.minimum(index, numbers.size - 1)] != events[:, 0]):
        raise ValueError(f"the run's events include particles not of species {species}.")
    span = steps + 2
    order = np.argsort(index * span + events[:, 1] + 1, kind="stable")
    keys = (index * span + events[:, 1] + 1)[order]
    places = events[order, 3]
    owners = index[order]
    t = np.arange(steps + 1)[:, None]
    query = np.arange(numbers.size)[None, :] * span + t
    last = np.searchsorted(keys, query, side="right") - 1
    valid = (last >= 0) & (owners[np.maximum(last, 0)] == np.arange(numbers.size)[None, :])
    return np.where(valid, places[np.maximum(last, 0)], initial[None, :])
