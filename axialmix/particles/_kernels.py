"""Compiled time-stepping loops of the two particle engines (see ``description`` for the process).

Both kernels advance a state in place for up to ``n_steps`` steps and count the steps done in
``progress[0]``, so the Python driver can run a long simulation in chunks, report between
chunks and keep everything done so far when interrupted.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from axialmix.particles._random import multivariate_hypergeometric, next_uniform

MAX_SPECIES = 256
"""Most species the identity engine handles."""


def species_bits(n_species: int) -> int:
    """Bits reserved for the species in an identity-engine slot ``(number << bits) | species``."""
    bits = 1
    while (1 << bits) < n_species:
        bits += 1
    return bits


FEED = -1
"""Source code of an identity event for a particle fed in."""
WEIR = -1
"""Destination code of an identity event (and of a move) for a particle leaving over the weir."""
TAGGED = -2
"""Source code of an identity event for a particle relabelled as tracer in place."""


@numba.njit(cache=True)
def advance_counts(
    counts,
    holdups,
    start,
    destination,
    count,
    handed_out,
    inlets,
    feed_counts,
    outflow_record,
    n_steps,
    progress,
):
    """Advance per-compartment species counts by up to ``n_steps`` steps (count engine).

    ``counts`` is ``(compartments, species)``; ``feed_counts[k, q]`` the species counts fed
    into ``inlets[q]`` at the end of step k of this chunk; ``outflow_record[k]`` receives the
    species counts that left over the weir during step k of this chunk. ``count`` (moves per
    table entry) and ``handed_out`` (per compartment) have one row, used at every step, or
    one row per step of this chunk (scheduled moves).
    """
    n_compartments, n_species = counts.shape
    arrivals = np.zeros((n_compartments, n_species), np.int64)
    selected = np.empty(n_species, np.int64)
    share = np.empty(n_species, np.int64)
    scheduled = count.shape[0] > 1
    for step in range(n_steps):
        row = step if scheduled else 0
        for i in range(n_compartments):
            handed = handed_out[row, i]
            if handed == 0:
                continue
            multivariate_hypergeometric(counts[i], holdups[i], handed, selected)
            for s in range(n_species):
                counts[i, s] -= selected[s]
            remaining = handed
            last = start[i + 1] - 1
            for e in range(start[i], start[i + 1]):
                if e == last:
                    for s in range(n_species):
                        share[s] = selected[s]
                else:
                    multivariate_hypergeometric(selected, remaining, count[row, e], share)
                    for s in range(n_species):
                        selected[s] -= share[s]
                    remaining -= count[row, e]
                target = destination[e]
                if target >= 0:
                    for s in range(n_species):
                        arrivals[target, s] += share[s]
                else:
                    for s in range(n_species):
                        outflow_record[step, s] += share[s]
        for j in range(n_compartments):
            for s in range(n_species):
                counts[j, s] += arrivals[j, s]
                arrivals[j, s] = 0
        for q in range(inlets.size):
            for s in range(n_species):
                counts[inlets[q], s] += feed_counts[step, q, s]
        progress[0] += 1


species_bits_of = numba.njit(cache=True)(species_bits)


@intrinsic
def _prefetch(typingctx, array, index):
    """Hint the CPU to fetch ``array[index]`` into cache for writing (no effect on results).

    Emits LLVM's ``llvm.prefetch`` (the ``prefetchw`` instruction on x86): the memory load
    starts now and the program goes on without waiting for it.
    """
    signature = types.void(array, index)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        data = context.make_array(array_type)(context, builder, args[0])
        pointer = cgutils.get_item_pointer(
            context, builder, array_type, data, [args[1]], wraparound=False
        )
        pointer = builder.bitcast(pointer, ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        function = cgutils.get_or_insert_function(
            builder.module,
            ir.FunctionType(ir.VoidType(), [pointer.type, i32, i32, i32]),
            "llvm.prefetch.p0i8",
        )
        # write access, keep in all cache levels, data cache
        builder.call(
            function, [pointer, ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)]
        )
        return context.get_dummy_value()

    return signature, codegen


@numba.njit(inline="always")
def _tally_species(moved, first, n, tally, mask):
    # Species counts of moved[first:first + n]. With two species a register sum of the
    # species bits avoids the serial read-modify-write chain of tally[species] += 1.
    if tally.size == 2:
        ones = 0
        for q in range(first, first + n):
            ones += moved[q] & mask
        tally[0] = n - ones
        tally[1] = ones
        return
    for s in range(tally.size):
        tally[s] = 0
    for q in range(first, first + n):
        tally[moved[q] & mask] += 1


@numba.njit(cache=True)
def advance_identities(
    slots,
    offsets,
    counts,
    start,
    destination,
    count,
    handed_out,
    inlets,
    feed_counts,
    outflow_record,
    first_step,
    n_steps,
    tracked,
    events,
    moved,
    picks,
    write,
    generator,
    progress,
):
    """Advance individual particles by up to ``n_steps`` steps (identity engine).

    ``slots[offsets[i]:offsets[i+1]]`` holds the particles of compartment i, each coded
    as ``(particle number << bits) | species`` (:func:`species_bits`). Selection is a
    partial Fisher-Yates shuffle of the compartment's slots (cost per particle moved, not
    held); arrivals overwrite the slots just handed out, which balance guarantees are
    exactly as many (``count`` and ``handed_out`` as in :func:`advance_counts`: one row, or
    one per step of the chunk). ``counts`` is kept up to date move by move. Moves of particles whose
    species is ``tracked`` are written to ``events`` as ``(particle, step, from, to)``;
    the kernel stops early, before a step
    whose events might not fit. ``progress`` holds ``[steps done, events written, next
    particle number]``.

    Positions are drawn as ``floor(U * n)`` from a 53-bit uniform U of the xoshiro256**
    state ``generator`` (advanced in place): each of the n outcomes
    has probability ``1/n`` to within a relative ``n * 2**-53`` (about 1e-9 for a hold-up
    of 10**7), far below anything a simulation can resolve, and about twice as fast as an
    exact bounded integer.
    """
    n_compartments, n_species = counts.shape
    bits = species_bits_of(n_species)
    mask = (1 << bits) - 1
    track_any = False
    for s in range(tracked.size):
        if tracked[s]:
            track_any = True
    per_step_events = moved.size
    tally = np.zeros(n_species, np.int64)
    scheduled = count.shape[0] > 1
    for step in range(n_steps):
        row = step if scheduled else 0
        if track_any:
            fed = 0
            for q in range(inlets.size):
                for s in range(n_species):
                    fed += feed_counts[step, q, s]
            if progress[1] + per_step_events + fed > events.shape[0]:
                return
        global_step = first_step + step
        pointer = 0
        for i in range(n_compartments):
            handed = handed_out[row, i]
            if handed == 0:
                continue
            base = offsets[i]
            held = offsets[i + 1] - base
            # Draw all positions first, asking for each slot's cache line as it is drawn,
            # then swap: the memory loads overlap each other and the generator's arithmetic
            # instead of stalling the swaps one by one. With 10**7 particles (40 MB of
            # slots, beyond the last-level cache) this makes the run about 3x faster.
            for k in range(handed):
                r = base + k + int(next_uniform(generator) * (held - k))
                picks[k] = r
                _prefetch(slots, r)
            for k in range(handed):
                r = picks[k]
                # Fisher-Yates swap, except that the chosen particle is not written back to
                # slot base + k: the front slots are overwritten by arrivals below.
                moved[pointer] = slots[r]
                slots[r] = slots[base + k]
                pointer += 1
        for i in range(n_compartments):
            write[i] = offsets[i]
        pointer = 0
        for i in range(n_compartments):
            for e in range(start[i], start[i + 1]):
                target = destination[e]
                n_moved = count[row, e]
                if target >= 0:
                    w = write[target]
                    for q in range(n_moved):
                        slots[w + q] = moved[pointer + q]
                    write[target] = w + n_moved
                _tally_species(moved, pointer, n_moved, tally, mask)
                pointer += n_moved
                for s in range(n_species):
                    counts[i, s] -= tally[s]
                    if target >= 0:
                        counts[target, s] += tally[s]
                    else:
                        outflow_record[step, s] += tally[s]
                if not track_any:
                    continue
                for p in range(pointer - n_moved, pointer):
                    code = moved[p]
                    species = code & mask
                    if tracked[species]:
                        n = progress[1]
                        events[n, 0] = code >> bits
                        events[n, 1] = global_step
                        events[n, 2] = i
                        events[n, 3] = target
                        progress[1] = n + 1
        for q in range(inlets.size):
            j = inlets[q]
            for s in range(n_species):
                for _ in range(feed_counts[step, q, s]):
                    number = progress[2]
                    progress[2] = number + 1
                    slots[write[j]] = (number << bits) | s
                    write[j] += 1
                    counts[j, s] += 1
                    if track_any and tracked[s]:
                        n = progress[1]
                        events[n, 0] = number
                        events[n, 1] = global_step
                        events[n, 2] = FEED
                        events[n, 3] = j
                        progress[1] = n + 1
        progress[0] += 1
