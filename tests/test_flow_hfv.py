"""HFV local matrices: symmetry, positivity, exactness for affine pressures (pure NumPy)."""

import numpy as np
import pytest

from poromech.flow.hfv import (
    cell_gradients,
    cell_matrices,
    fracture_face_matrices,
    fracture_half_transmissibilities,
    permeability_tensors,
    series_matrices,
)
from poromech.flow.system import (
    cell_elements,
    pair_elements,
    shifted_cell_elements,
)

rng = np.random.default_rng(1234)


def random_triangles(n: int):
    """Random (also flat) triangles with their HFV geometry: area, normal, offset, volume."""
    x = rng.uniform(-1.0, 1.0, (n, 3, 2))
    x[: n // 4, 2] = x[: n // 4, 0] + 0.05 * (x[: n // 4, 1] - x[: n // 4, 0]) + [0.0, 0.02]
    facets = np.array([[1, 2], [0, 2], [0, 1]])
    a, b = x[:, facets[:, 0]], x[:, facets[:, 1]]
    t = b - a
    area = np.linalg.norm(t, axis=2)
    normal = np.stack([-t[..., 1], t[..., 0]], axis=-1) / area[..., None]
    centroid = x.mean(axis=1)
    offset = 0.5 * (a + b) - centroid[:, None]
    normal *= np.sign(np.einsum("nfi,nfi->nf", offset, normal))[..., None]
    e1, e2 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]
    volume = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return area, normal, offset, volume, centroid


def random_tensors(n: int):
    """SPD tensors with anisotropy up to 1e3 and arbitrary orientation."""
    angle = rng.uniform(0, np.pi, n)
    k1 = 10.0 ** rng.uniform(-1, 2, n)
    k2 = k1 * 10.0 ** rng.uniform(-3, 0, n)
    c, s = np.cos(angle), np.sin(angle)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    D = np.zeros((n, 2, 2))
    D[:, 0, 0], D[:, 1, 1] = k1, k2
    return R @ D @ R.transpose(0, 2, 1)


@pytest.fixture(scope="module")
def cells():
    n = 400
    area, normal, offset, volume, centroid = random_triangles(n)
    perm = random_tensors(n)
    A = cell_matrices(area, normal, offset, volume, perm, np.sqrt(2.0))
    return area, normal, offset, volume, centroid, perm, A


def test_cell_matrices_spd(cells):
    *_, A = cells
    assert np.abs(A - A.transpose(0, 2, 1)).max() <= 1e-12 * np.abs(A).max()
    eig = np.linalg.eigvalsh(A)
    cond = eig[:, -1] / eig[:, 0]
    assert np.all(eig[:, 0] > 0)
    assert np.all(np.isfinite(cond))


def test_cell_matrices_exact_for_affine(cells):
    """F_{K,σ} = -|σ| Λ ∇p · n for p affine (p_K at x_K, p_σ at x_σ), any Λ and shape."""
    area, normal, offset, volume, centroid, perm, A = cells
    grad = rng.normal(size=(len(A), 2))
    jump = np.einsum("nfi,ni->nf", offset, grad)  # p_σ - p_K
    flux = np.einsum("nfg,ng->nf", A, -jump)  # F = A (p_K - p_σ)
    exact = -area * np.einsum("nfi,nij,nj->nf", normal, perm, grad)
    scale = np.abs(exact).max(axis=1, keepdims=True)
    assert np.abs(flux - exact).max() <= 1e-11 * scale.max()
    g = cell_gradients(area, normal, volume, np.zeros(len(A)), jump)
    assert np.abs(g - grad).max() <= 1e-11


def test_stabilization_independent_of_consistency(cells):
    """β only changes the stabilization: both matrices give the same affine fluxes."""
    area, normal, offset, volume, centroid, perm, A = cells
    A1 = cell_matrices(area, normal, offset, volume, perm, 0.3)
    grad = np.array([0.7, -1.3])
    dp = np.einsum("nfi,i->nf", offset, grad)
    assert np.abs(np.einsum("nfg,ng->nf", A - A1, dp)).max() <= 1e-10 * np.abs(A).max()
    assert np.abs(A - A1).max() > 1e-3 * np.abs(A).max()


def test_cell_elements_kernel_and_shift(cells):
    """Constants are in the kernel, in trace and in shifted (δ = trace - p_f) variables."""
    *_, A = cells
    for shifted in (np.zeros((len(A), 3), bool), rng.random((len(A), 3)) < 0.5):
        E = shifted_cell_elements(cell_elements(A), shifted)
        assert E.shape == (len(A), 7, 7)
        one = np.ones((len(A), 7))
        one[:, 1:4][shifted] = 0.0  # δ = 0 for a constant pressure
        one[:, 4:][~shifted] = 0.0  # unused p_f slots
        assert np.abs(np.einsum("nij,nj->ni", E, one)).max() <= 1e-10 * np.abs(E).max()
        assert np.all(np.linalg.eigvalsh(E)[:, 0] >= -1e-10 * np.abs(E).max())


def test_fracture_and_pair_elements():
    T = np.array([[2.0, 3.0]])
    E = cell_elements(np.diag(T[0])[None])
    assert np.allclose(E[0], [[5, -2, -3], [-2, 2, 0], [-3, 0, 3]])
    assert np.allclose(E[0] @ np.ones(3), 0)
    P = pair_elements(np.array([4.0, 4.0]), np.array([False, True]))
    assert np.allclose(P[0], [[4, -4], [-4, 4]]) and np.allclose(P[1], [[4, 0], [0, 0]])
    # 1D HFV with β = 1 is the two-point flux with half lengths (DESIGN §5, fracture face σ)
    assert np.allclose(fracture_half_transmissibilities(np.array([0.5]), np.array([3.0])), 12.0)


def test_permeability_tensors():
    k = permeability_tensors([np.array([1.0]), np.array([0.2]), np.array([3.0])])
    assert np.allclose(k[0], [[1.0, 0.2], [0.2, 3.0]])
    assert np.allclose(permeability_tensors([np.array([2.0])])[0], 2 * np.eye(2))
    assert np.allclose(permeability_tensors([np.array([2.0]), np.array([5.0])])[0],
                       np.diag([2.0, 5.0]))


def test_permeability_tensors_3d():
    one = np.array([1.0])
    k = permeability_tensors([one, 0.1 * one, 0.2 * one, 2 * one, 0.3 * one, 3 * one], 3)
    assert np.array_equal(k[0], [[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]])
    assert np.array_equal(permeability_tensors([one, 2 * one, 3 * one], 3)[0], np.diag([1, 2, 3]))
    assert np.array_equal(permeability_tensors([2 * one], 3)[0], 2 * np.eye(3))
    with pytest.raises(ValueError, match="1, 3 or 6"):
        permeability_tensors([one, one], 3)


def random_fracture_faces(n: int):
    """Random triangles on random planes in 3D: edges ``(n, 3, 2, 3)``, frames, vertices."""
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    t1 = np.cross(normal, rng.normal(size=(n, 3)))
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(normal, t1)
    frame = np.stack([t1, t2], 1)
    uv = rng.uniform(-1, 1, (n, 3, 2))
    x = rng.normal(size=(n, 1, 3)) + np.einsum("nvk,nki->nvi", uv, frame)
    order = [[1, 2], [2, 0], [0, 1]]  # edge i opposite vertex i, in a mesh's arbitrary order
    return x[:, order], frame, x


def test_fracture_face_matrices_exact_for_affine():
    """The in-plane HFV of a triangle: SPD, and exact fluxes ``-|e| ∇p·n_e`` for affine p."""
    edges, frame, x = random_fracture_faces(300)
    A = fracture_face_matrices(edges, frame, np.sqrt(2.0))
    assert np.allclose(A, A.transpose(0, 2, 1), rtol=0, atol=1e-12 * np.abs(A).max())
    assert np.linalg.eigvalsh(A).min() > 0
    grad = np.einsum("k,nki->ni", [2.0, -1.0], frame)  # an in-plane gradient
    mid = edges.mean(axis=2)
    centroid = x.mean(axis=1)
    dp = -np.einsum("nei,ni->ne", mid - centroid[:, None], grad)  # p_σ - p_e
    flux = np.einsum("nij,nj->ni", A, dp)
    vec = edges[:, :, 1] - edges[:, :, 0]
    out = np.cross(vec, np.cross(mid - centroid[:, None], vec))  # in-plane, outward
    out /= np.linalg.norm(out, axis=2)[..., None]
    exact = -np.linalg.norm(vec, axis=2) * np.einsum("nei,ni->ne", out, grad)
    assert np.allclose(flux, exact, rtol=0, atol=1e-10)


def test_series_matrices():
    """Diagonal matrices give the 2D rule T/(1 + T R); no resistance leaves A unchanged."""
    T = rng.uniform(0.5, 2.0, (50, 2))
    R = rng.uniform(0.0, 3.0, (50, 2)) * (rng.uniform(size=(50, 2)) > 0.3)
    D = np.zeros((50, 2, 2))
    D[:, [0, 1], [0, 1]] = T
    S = series_matrices(D, R)
    assert np.allclose(S[:, [0, 1], [0, 1]], T / (1 + T * R), rtol=1e-14)
    edges, frame, _ = random_fracture_faces(40)
    A = fracture_face_matrices(edges, frame, np.sqrt(2.0))
    assert np.array_equal(series_matrices(A, np.zeros((40, 3))), A)
    R3 = rng.uniform(0.0, 2.0, (40, 3))
    S3 = series_matrices(A, R3)
    expected = np.linalg.inv(np.linalg.inv(A) + R3[:, :, None] * np.eye(3))
    assert np.allclose(S3, expected, rtol=1e-10, atol=1e-12)
    blocked = series_matrices(A, np.where(np.arange(3) == 0, np.inf, 0.0)[None].repeat(40, 0))
    assert np.abs(blocked[:, 0]).max() < 1e-15 * np.abs(A).max()  # round-off only
