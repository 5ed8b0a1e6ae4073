"""Fracture intersections: the permeability of the region where two fractures overlap.

A network node ``e`` where several fractures meet is the centre of their intersection and
carries the intersection pressure ``p_e`` (DESIGN §5 "Intersections"). Seen as strips of width
``d``, two fractures overlap around ``e``; a *branch* (a face ``σ`` of fracture ``i`` ending at
``e``) that crosses a fracture ``j`` running *through* ``e`` spends the last ``d_j / 2`` of its
path to ``e`` inside that overlap. The half-face transmissibility ``T_{σ,e} = 2 C_σ / |σ|``
(``C_σ = K_{τ,σ} d_σ``) counts that segment with the branch's own tangential permeability
``K_{τ,σ}``; the overlap belongs to both fractures, and for flow along ``i`` it has the harmonic
mean of the permeabilities the two fractures give it, ``K_{τ,σ}`` (along ``i``) and ``Λ_{n,j}``
(across ``j``):

    K_I = 2 / (1/K_{τ,σ} + 1/Λ_{n,j}).

Replacing ``K_{τ,σ}`` by ``K_I`` on that segment (length ``d_j/2``, cross-section ``d_σ``)
adds the resistance

    ΔR_{σ,e} = (d_j / (2 d_σ)) (1/K_I - 1/K_{τ,σ}) = (d_j / (4 d_σ)) (1/Λ_{n,j} - 1/K_{τ,σ}),

kept only where positive (the crossed fracture is the less permeable one), and averaged over
the faces at ``e`` of every fracture ``j ≠ i`` running through ``e``. In series with the half
face, ``T*_{σ,e} = T_{σ,e} / (1 + T_{σ,e} ΔR_{σ,e})``. Equal permeabilities give ``ΔR = 0``:
conductive-conductive (and blocking-blocking) intersections are exactly as before. A fracture
that *ends* at ``e`` (a T stem, fractures ending together) is crossed by nobody, so the
branches of a fracture running through a T junction are unchanged, as are nodes of a single
fracture, tips and fracture ends on ∂Ω. ``docs/flow.md`` ("Intersections") derives the cases.

Which fractures run through a node is settled once, on the rank that owns the node (its dof),
from the fracture indices of every face end there; the crossed faces' data are then averaged
there at every coefficient update (two all-to-all exchanges of face-end values, collective).
The result does not depend on the partition.

In 3D the nodes are the edges of the fracture triangles and the intersections are lines made
of such edges; the same rule applies per edge, the overlap segment becoming a strip of width
``d_j / 2`` along the edge, so the resistance of the edge is ``ΔR_{σ,e} / |e|`` in series with
the face's HFV matrix (:func:`poromech.flow.hfv.series_matrices`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from scipy.sparse import csr_matrix

from poromech.flow.dofs import FlowDofs

__all__ = [
    "FractureCrossings",
    "crossing_matrix",
    "crossing_resistance",
    "series_transmissibilities",
]

Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def crossing_resistance(crossed: Array, conductivity: Array, aperture: Array) -> Array:
    """Added resistance ``ΔR_{σ,e}`` of the overlap segment of each face end (1/m²).

    ``ΔR = (d_j/(4 d_σ)) (1/Λ_{n,j} - 1/K_{τ,σ})`` where positive (docs/flow.md,
    "Intersections"): the segment of length ``d_j/2`` inside the crossed fracture ``j`` gets the
    harmonic mean of ``K_{τ,σ}`` and ``Λ_{n,j}`` instead of ``K_{τ,σ}``.

    Args:
        crossed: Means over the crossed faces at each end of ``[d_j/(4 Λ_{n,j}), d_j]``,
            ``(nf, 2, 2)`` (1/m and m); zero where the end crosses no fracture.
        conductivity: Branch conductivities ``C_σ = K_{τ,σ} d_σ`` ``(nf,)`` (m³).
        aperture: Branch apertures ``d_σ`` ``(nf,)`` (m).

    Returns:
        ``ΔR = max(0, mean(d_j/(4Λ_{n,j})) - mean(d_j)/(4 K_{τ,σ})) / d_σ``, ``(nf, 2)``.
    """
    k_tau = (conductivity / aperture)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        excess = crossed[..., 0] - crossed[..., 1] / (4.0 * k_tau)
    return np.where(excess > 0, excess, 0.0) / aperture[:, None]


def series_transmissibilities(half: Array, resistance: Array) -> Array:
    """``T*_{σ,e} = T_{σ,e} / (1 + T_{σ,e} ΔR_{σ,e})``: half face and intersection in series.

    Args:
        half: Half-face transmissibilities ``T_{σ,e}`` ``(nf, 2)`` (m²).
        resistance: Added resistances ``ΔR_{σ,e}`` ``(nf, 2)`` (1/m²), possibly infinite.

    Returns:
        ``(nf, 2)`` (m²); ``half`` itself where ``ΔR = 0``.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        out = half / (1.0 + half * resistance)
    return np.where(resistance > 0, np.nan_to_num(out, nan=0.0), half)


def crossing_matrix(node: IntArray, fracture: IntArray) -> csr_matrix:
    """Averaging matrix over the faces crossed by each face end (local).

    Args:
        node: Node key of each face end (global node dof), ``(n,)``.
        fracture: Fracture index of each face end, ``(n,)``.

    Returns:
        ``W`` ``(n, n)`` with ``W[r, s] = 1/n_r`` when end ``s`` lies at the node of ``r``, on a
        fracture other than ``r``'s that runs through that node (two or more face ends of that
        fracture there), ``n_r`` the number of such ends. Rows of uncrossed ends are empty.
    """
    n = len(node)
    order = np.lexsort((fracture, node))
    k, f = node[order], fracture[order]
    new_pair = np.r_[True, (k[1:] != k[:-1]) | (f[1:] != f[:-1])]
    pair = np.cumsum(new_pair) - 1
    through = (np.bincount(pair) >= 2)[pair]
    new_node = np.r_[True, k[1:] != k[:-1]]
    first = np.flatnonzero(new_node)
    group = np.cumsum(new_node) - 1
    size = np.diff(np.r_[first, n])[group]
    rows = np.repeat(np.arange(n), size)
    within = np.arange(len(rows)) - np.repeat(np.cumsum(size) - size, size)
    cols = first[group[rows]] + within
    keep = (f[rows] != f[cols]) & through[cols]
    rows, cols = rows[keep], cols[keep]
    weight = 1.0 / np.bincount(rows, minlength=n)[rows]
    return csr_matrix((weight, (order[rows], order[cols])), shape=(n, n))


class FractureCrossings:
    """Which owned fracture-face ends cross which faces, and averages over those (collective).

    Args:
        comm: The communicator of the flow problem.
        dofs: The HFV numbering (node dofs of the owned fracture faces, ownership ranges).
        fracture: Fracture index of each owned fracture face ``(nf,)``.

    Attributes:
        crossing: ``(nf, d)`` mask of the owned face ends (nodes) that cross another fracture.
        num_crossing: Global number of such face ends.
    """

    def __init__(self, comm: MPI.Comm, dofs: FlowDofs, fracture: npt.NDArray):
        self.comm = comm
        self._nf = len(dofs.fracture)
        self._nv = dofs.node.shape[1] if dofs.node.ndim == 2 else 2
        key = dofs.local_to_global(dofs.node.ravel())
        starts = np.asarray(comm.allgather(dofs.start))
        dest = np.searchsorted(starts, key, side="right") - 1
        self._order = np.argsort(dest, kind="stable")
        self._send_counts = np.bincount(dest, minlength=comm.size)
        fid = np.repeat(np.asarray(fracture, dtype=np.int64), self._nv)
        recv = self._to_owners(np.column_stack([key, fid]).astype(np.int64))
        self._recv_counts = np.array([len(r) for r in recv])
        rec = np.concatenate(recv)
        self._W = crossing_matrix(rec[:, 0], rec[:, 1])
        crossed = np.diff(self._W.indptr) > 0
        self.crossing = self._from_owners(crossed.astype(np.float64)).reshape(-1, self._nv) > 0.5
        self.num_crossing = int(comm.allreduce(int(self.crossing.sum())))

    def _to_owners(self, values: npt.NDArray) -> list[npt.NDArray]:
        """Send per-end values to the owners of their nodes; the received blocks (collective)."""
        ordered = values[self._order]
        parts = np.split(ordered, np.cumsum(self._send_counts)[:-1])
        return self.comm.alltoall(parts)

    def _from_owners(self, values: Array) -> Array:
        """Return owner-side values per received end to the senders, in face-end order."""
        parts = np.split(values, np.cumsum(self._recv_counts)[:-1])
        back = np.concatenate(self.comm.alltoall(parts))
        out = np.empty_like(back)
        out[self._order] = back
        return out

    def averages(self, values: Array) -> Array:
        """Means of per-face values over the faces crossed at each owned face end (collective).

        Args:
            values: ``(nf, k)`` values of the owned fracture faces.

        Returns:
            ``(nf, d, k)``, zero where the end crosses no fracture.
        """
        values = np.asarray(values, dtype=float)
        k = values.shape[1]
        if self.num_crossing == 0:
            return np.zeros((self._nf, self._nv, k))
        recv = self._to_owners(np.repeat(values, self._nv, axis=0))
        mean = self._W @ np.concatenate(recv).reshape(-1, k)
        return self._from_owners(mean).reshape(self._nf, self._nv, k)
