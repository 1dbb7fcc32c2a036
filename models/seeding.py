"""One seed, spawned into independent named random streams.

Every random component of a run (the plant noise, the initial state, a link set's
per-message delays, each link's loss, the random consensus weights, ...) draws from
its own :class:`numpy.random.Generator`, derived from one root seed by
:class:`numpy.random.SeedSequence`. Streams are addressed by *name* rather than by
spawn order, so adding a component never changes the numbers another component
sees (the links of one set share their stream, :data:`SEED_LAYOUT`). numpy's global
random state is never touched.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["SEED_LAYOUT", "SeedLike", "as_seed_sequence", "stream", "child_sequence"]

SeedLike = int | np.random.SeedSequence | None

#: Version of the layout of the random streams, recorded in every result and trace.
#: 1: one stream per (trial, link) for per-message link draws; 2: one stream per trial
#: for the whole link set, drawn as (messages, links) blocks
#: (:class:`netsim.models.delays.LinkBlockDraws`). The same seed gives other delays
#: (and so other numbers) under another layout.
SEED_LAYOUT = 2


def as_seed_sequence(seed: SeedLike) -> np.random.SeedSequence:
    """Normalise a seed argument into a :class:`numpy.random.SeedSequence`.

    Parameters
    ----------
    seed : int, SeedSequence or None
        An integer seed, an existing sequence (returned unchanged), or None for
        fresh OS entropy (non-reproducible).

    Returns
    -------
    numpy.random.SeedSequence
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if seed is None:
        return np.random.SeedSequence()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return np.random.SeedSequence(int(seed))


def _name_key(name: str) -> int:
    return zlib.crc32(name.encode("utf-8"))


def child_sequence(seed: SeedLike, *names: str | int) -> np.random.SeedSequence:
    """Derive the independent child sequence addressed by a path of names.

    Parameters
    ----------
    seed : int, SeedSequence or None
        Root seed.
    *names : str or int
        Path of the component, e.g. ``("trial", 3, "plant")``. Integers are used
        as they are, strings through a stable CRC32 hash.

    Returns
    -------
    numpy.random.SeedSequence
        A sequence whose spawn key extends the root's by the path.
    """
    root = as_seed_sequence(seed)
    key = tuple(int(n) if isinstance(n, int | np.integer) else _name_key(str(n)) for n in names)
    return np.random.SeedSequence(
        entropy=root.entropy, spawn_key=tuple(root.spawn_key) + key, pool_size=root.pool_size
    )


def stream(seed: SeedLike, *names: str | int) -> np.random.Generator:
    """Return the random generator of one named component.

    Parameters
    ----------
    seed : int, SeedSequence or None
        Root seed.
    *names : str or int
        Path of the component, see :func:`child_sequence`.

    Returns
    -------
    numpy.random.Generator
        A PCG64 generator independent of every other path's.
    """
    return np.random.Generator(np.random.PCG64(child_sequence(seed, *names)))
